"""A blocked nozzle (``warp_sph.run.emission.ParticleFlow._unblocked``): an emitter whose layers would land on
fluid that has not cleared the nozzle emits only the free slots. Found on the river scene at r = 0.0125 m
(WCSPH): the jet, slowed by the pool that rose to the nozzle, was overlapped by the next layer 0.12 d away,
and the density spike (+45 %) turned into +43 % of the scene's energy in one frame (the energy rule stopped it)."""
import numpy as np

from warp_sph.run.emission import BLOCKED_GAP
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict

# a nozzle half under water: the pool at rest covers its lower half, whose layers would land inside the fluid
SUBMERGED = {
    "name": "submerged", "particle_radius": 0.025, "duration": 1.0, "fps": 24.0, "solver": "wcsph",
    "container": {"min": [0.0, 0.0, 0.0], "max": [0.5, 0.4, 0.4]},
    "fluid": [{"min": [0.0, 0.0, 0.0], "max": [0.5, 0.4, 0.15]}],
    "emitters": [{"shape": "rectangle", "position": [0.1, 0.2, 0.15], "direction": [1.0, 0.0, 0.0],
                  "width": 0.2, "height": 0.1, "speed": 1.0}],
    "output": {"surface": False, "usd": False},
}


def test_submerged_nozzle_emits_only_free_slots(device):
    """Every emitted particle starts at least BLOCKED_GAP d from every particle already there (brute-force
    distances at each frame's start), the blocked ones are counted, and WCSPH runs on (before: the overlap
    blew up and the energy rule stopped the run)."""
    sim = Simulation(scene_from_dict(SUBMERGED, source="submerged.toml"), device=device)
    d = sim.scene.spacing
    flow = sim.flow
    gaps = []
    begin = flow.begin_frame

    def checked():
        old = sim.get_field("particle_x")
        n0, emitted = len(old), flow.emitted
        begin()
        new = sim.get_field("particle_x")[n0:]
        assert len(new) == flow.emitted - emitted
        if len(new):
            gaps.append(np.sqrt(((new[:, None, :] - old[None, :, :]) ** 2).sum(-1)).min() / d)
        return True

    flow.begin_frame = checked
    for _ in range(4):
        s = sim.advance_frame()
    assert s.flow["blocked"] > 0 and s.flow["particles"] == sim.model.fluid_count
    assert gaps and min(gaps) >= BLOCKED_GAP - 1e-4, gaps
    assert np.isfinite(sim.get_field("particle_v")).all()


def test_energy_error_counts_the_flow(device):
    """The energy rule's error reports the rise the rule judged: the flow's exchanged energy subtracted
    (before: the raw rise with the emitted energy in it, "226 J = 129 %" for a river whose rule read 0.98 %).
    A pump stage on the flow scene is stopped in frame 1, and the message's percentage is the rule's growth
    (before: 222 % for a growth of 36.6 %)."""
    import re

    import pytest
    from test_emission import BASE
    from test_energy_watchdog import _pump
    from warp_sph.core.errors import SimulationError

    sim = Simulation(scene_from_dict({**BASE, "solver": "dfsph"}, source="flow.toml"), device=device)
    sim.graph.insert(_pump(3.0 * 9.81))
    with pytest.raises(SimulationError, match="the total energy rose by") as err:
        for _ in range(24):
            sim.advance_frame()
    watch = sim.watchdog.energy
    assert abs(sim.flow.exchanged) > 0.01 * watch.scale  # the flow's account is not negligible
    said = float(re.search(r"J = ([-0-9.e+]+) %", str(err.value)).group(1))
    assert said == pytest.approx(100 * watch.growth(watch.last), rel=2e-3), str(err.value)
    assert "exchanged by emitters and sinks" in str(err.value)
