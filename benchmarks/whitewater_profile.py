"""Where the whitewater stage's time goes: process CPU time per substep of each of its kernel launches.

    python -m benchmarks.whitewater_profile grid 30 trapped_air_rate=4000.0 wave_crest_rate=50000.0

runs the default dam break (no output) for that many frames with ``[whitewater]`` (``fluid_sampling`` =
the first argument, grid or walk; further ``key=value`` set whitewater keys; default rates 4000 / 50000,
SPlisHSPlasH's), the first frame not counted (kernel loading). Wrap it in ``flock
/tmp/warp_sph_bench.lock`` on a shared machine. A diagnostic beside ``warp-sph bench whitewater``.
"""
from __future__ import annotations

import collections
import sys
import time
import tomllib
from pathlib import Path


def main(argv: list[str]) -> None:
    import numpy as np
    import warp as wp

    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import scene_from_dict

    mode, frames = argv[0], int(argv[1])
    scenes = Path(__file__).resolve().parent.parent / "scenes"
    d = tomllib.loads((scenes / "dam_break.toml").read_text())
    d["output"] = {"usd": False, "surface": False}
    d["whitewater"] = {"trapped_air_rate": 4000.0, "wave_crest_rate": 50000.0, "fluid_sampling": mode}
    for item in argv[2:]:
        k, v = item.split("=")
        d["whitewater"][k] = float(v) if "." in v else int(v)
    sim = Simulation(scene_from_dict(d))
    ww = sim.whitewater
    module = sys.modules[type(ww).__module__]
    kernel_s = collections.defaultdict(float)
    stage_s = [0.0]
    plain_launch, plain_step = module.launch, ww.step

    def timed_launch(kernel, *a, **k):
        t = time.process_time()
        plain_launch(kernel, *a, **k)
        wp.synchronize()
        kernel_s[kernel.key.split("__")[-1]] += time.process_time() - t

    def timed_step(dt):
        t = time.process_time()
        plain_step(dt)
        stage_s[0] += time.process_time() - t

    module.launch, ww.step = timed_launch, timed_step
    sim.advance_frame()  # kernel loading
    kernel_s.clear()
    stage_s[0] = 0.0
    s0, t0, counts = sim.state.step, time.process_time(), []
    for _ in range(frames - 1):
        sim.advance_frame()
        counts.append(ww.count)
    steps = sim.state.step - s0
    print(f"{mode} {' '.join(argv[2:])}: {steps} steps, {1e3 * (time.process_time() - t0) / steps:.2f} CPU ms/step, "
          f"whitewater stage {1e3 * stage_s[0] / steps:.2f}; particles mean {np.mean(counts):.0f}, max {max(counts)}")
    print("  CPU ms/step per kernel:", {k: round(1e3 * v / steps, 2) for k, v in kernel_s.items()},
          f"scans, reads and the rest: {1e3 * (stage_s[0] - sum(kernel_s.values())) / steps:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
