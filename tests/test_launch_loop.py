"""Loops of recorded launches (core/launch.py ``Replays``, ``run_loop``) and DFSPH's solves through them:
the same values as launching each pass, for 1, 2 and 3 CPU threads; a changed argument is re-bound."""
import numpy as np
import pytest
import warp as wp

from warp_sph.core import launch as core_launch
from warp_sph.core.launch import Replays, launch, run_loop
from warp_sph.run.simulation import Simulation


@wp.kernel(enable_backward=False)
def _smooth(tid_offset: int, x: wp.array(dtype=float), y: wp.array(dtype=float)):
    """y_i = (x_{i-1} + x_{i+1}) / 2 (periodic): reads other ranges' x."""
    i = wp.tid() + tid_offset
    n = x.shape[0]
    y[i] = 0.5 * (x[(i + n - 1) % n] + x[(i + 1) % n])


@wp.kernel(enable_backward=False)
def _shift(tid_offset: int, y: wp.array(dtype=float), c: float, x: wp.array(dtype=float)):
    """x_i = y_i + c."""
    i = wp.tid() + tid_offset
    x[i] = y[i] + c


@wp.kernel(enable_backward=False)
def _count(x: wp.array(dtype=float), counter: wp.array(dtype=float)):
    """One thread: counter[0] += 1, counter[1] = x_0 (a serial pass)."""
    counter[0] = counter[0] + 1.0
    counter[1] = x[0]


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_run_loop_passes_see_the_last_pass_and_stop(monkeypatch, threads):
    """Sweeps of smooth -> shift -> count over 3,500 values (3 ranges of >= 1,024): each pass reads what
    the other threads' ranges wrote in the pass before (a missing barrier reads stale neighbours); the
    loop stops on the sweep its stop test says; a changed scalar and a swapped array are re-bound."""
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", str(threads))
    rng = np.random.default_rng(3)
    n = 3500
    x0 = rng.random(n).astype(np.float32)
    x, y = wp.array(x0, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu")
    y2 = wp.zeros(n, dtype=float, device="cpu")
    counter = wp.zeros(2, dtype=float, device="cpu")
    view = counter.numpy()
    expect = x0.copy()
    replays = Replays()
    for c, scratch, sweeps in [(1.0, y, 5), (1.0, y, 4), (-2.0, y2, 6)]:
        passes = [[replays.get(_smooth, n, [x], [scratch], device="cpu")],
                  [replays.get(_shift, n, [scratch, c], [x], device="cpu")],
                  [replays.get(_count, 1, [x], [counter], device="cpu")]]
        assert len(passes[0][0].cmds) == threads
        start = view[0]
        ran = run_loop(passes, 100, lambda s, start=start, sweeps=sweeps: view[0] - start >= sweeps)
        assert ran == sweeps
        for _ in range(sweeps):
            expect = (0.5 * (np.roll(expect, 1) + np.roll(expect, -1)) + np.float32(c)).astype(np.float32)
        np.testing.assert_allclose(x.numpy(), expect, rtol=1e-6)
        assert view[1] == x.numpy()[0]
    assert np.abs(y2.numpy()).max() > 0  # the swapped scratch array was written


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_run_loop_runs_before_and_after_once_in_order(monkeypatch, threads):
    """``before`` runs once ahead of the sweeps and ``after`` once behind the last one, in the same hand-off:
    x = x0 + 1 (before), then 4 sweeps of smoothing, then y = smoothed x (after, every range reading what the
    other ranges wrote in the last sweep); the serial _count groups count the sweeps (the stop test ends the
    loop after 4) and the one-thread groups before and after (once each)."""
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", str(threads))
    n = 3500
    x0 = np.random.default_rng(5).random(n).astype(np.float32)
    x, y = wp.array(x0, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu")
    counter = wp.zeros(2, dtype=float, device="cpu")
    view = counter.numpy()
    replays = Replays()
    count = [[replays.get(_count, 1, [x], [counter], device="cpu", tag=tag)] for tag in ("first", "last")]
    before = [count[0],  # one thread's group: runs before the other threads start
              [replays.get(_shift, n, [x, 1.0], [y], device="cpu", tag="before 1")],
              [replays.get(_shift, n, [y, 0.0], [x], device="cpu", tag="before 2")]]
    passes = [[replays.get(_smooth, n, [x], [y], device="cpu")], [replays.get(_shift, n, [y, 0.0], [x], device="cpu")],
              [replays.get(_count, 1, [x], [counter], device="cpu")]]
    after = [[replays.get(_smooth, n, [x], [y], device="cpu", tag="after")], count[1]]  # the last: after they stop
    ran = run_loop(passes, 10, lambda s: view[0] >= 5, before=before, after=after)
    assert ran == 4 and view[0] == 6
    expect = x0 + np.float32(1.0)
    for _ in range(4):
        expect = (0.5 * (np.roll(expect, 1) + np.roll(expect, -1))).astype(np.float32)
    np.testing.assert_allclose(x.numpy(), expect, rtol=1e-6)
    np.testing.assert_allclose(y.numpy(), 0.5 * (np.roll(expect, 1) + np.roll(expect, -1)), rtol=1e-6)


def test_split_launches_share_the_loop_threads_and_fall_back_inside_a_loop(monkeypatch):
    """A split launch runs its ranges on run_loop's persistent threads (no thread pool made), a split launch
    from inside a run_loop callable (the threads busy at its barrier) falls back to the pool instead of
    waiting forever, and an error in another thread's range reaches the caller, after which the threads
    still work."""
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", "2")
    monkeypatch.setattr(core_launch, "_pool", None)
    n = 3000
    x0 = np.arange(n, dtype=np.float32)
    x, y = wp.array(x0, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu")
    launch(_shift, n, [x, 2.0], [y], device="cpu")  # the first launch loads the module (one range)
    launch(_shift, n, [x, 3.0], [y], device="cpu")
    np.testing.assert_array_equal(y.numpy(), x0 + 3.0)
    assert core_launch._pool is None and core_launch._loop_workers is not None

    def nested():
        launch(_shift, n, [y, 1.0], [x], device="cpu")

    rec = Replays().get(_shift, n, [x, 0.5], [y], device="cpu")
    assert run_loop([[rec], [nested]], 2) == 2  # y = x + 0.5, x = y + 1, twice
    np.testing.assert_array_equal(x.numpy(), x0 + 3.0)
    assert core_launch._pool is not None  # the nested launch's other range ran on the pool

    def fail():
        raise ValueError("range 1")

    with pytest.raises(ValueError, match="range 1"):
        core_launch._run_split([lambda: None, fail])
    launch(_shift, n, [x, -3.0], [y], device="cpu")
    np.testing.assert_array_equal(y.numpy(), x0)


def _block(steps_dt, threads, loop, monkeypatch):
    from test_dfsph import block_on_floor

    monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
    sim = Simulation(block_on_floor(nx=16, ny=16, nz=12, material={"xsph": 0.05, "viscosity": 1e-3},
                                    dfsph={"chebyshev": 0.5}), device="cpu")
    sim.solver.sweep_loop = loop
    figures = []
    for dt in steps_dt:
        sim.step(dt)
        s = sim.solver
        figures.append((s.last_iterations, s.last_density_error, s.last_divergence_iterations,
                        s.last_divergence_error))
    return sim.get_field("particle_x"), sim.get_field("particle_v"), sim.get_field("dfsph_pressure"), figures


@pytest.mark.parametrize("threads", ["1", "2"])
def test_dfsph_sweep_loop_is_bitwise_the_launch_per_pass(monkeypatch, threads):
    """DFSPH's search and solves through run_loop (recorded launches, re-bound when dt, and with it the
    scale, 1/dt and the divergence target, changes from step to step) give bitwise the state and
    iteration counts of the launch-per-pass path, with plain and Chebyshev sweeps."""
    dts = (4e-3, 3e-3, 3.5e-3)
    old = _block(dts, threads, False, monkeypatch)
    new = _block(dts, threads, True, monkeypatch)
    for a, b in zip(old[:3], new[:3]):
        assert np.array_equal(a, b)
    assert old[3] == new[3]
    assert all(f[0] >= 2 for f in new[3])


@wp.kernel(enable_backward=False)
def _affine(tid_offset: int, x: wp.array(dtype=float), a: float, v: wp.vec3, y: wp.array(dtype=float)):
    """y_i = a x_i + v_0 - v_2 (a scalar, a vector and two arrays per launch)."""
    i = wp.tid() + tid_offset
    y[i] = a * x[i] + v[0] - v[2]


@pytest.mark.parametrize("threads", [1, 2])
def test_replays_run_prepared_without_warps_per_launch_packing(monkeypatch, threads):
    """A replayed CPU launch calls the kernel with its argument struct packed once (``core.launch._prepared``),
    not through Warp's ``invoke`` (which packs every argument on each launch), and still computes what a fresh
    ``wp.launch`` computes after each change: a new scalar, a new vector, another output array, another size
    (NumPy oracle; bitwise, the same float32 operations)."""
    if not wp.__version__.startswith(core_launch.PREPARED_WARP_VERSIONS):
        pytest.skip(f"Warp {wp.__version__}: replays go through Warp's launch (PREPARED_WARP_VERSIONS)")
    from warp._src import context as warp_context

    monkeypatch.setenv("WARP_SPH_CPU_THREADS", str(threads))
    rng = np.random.default_rng(5)
    n = 4096
    x = wp.array(rng.random(n).astype(np.float32), dtype=float, device="cpu")
    y, y2 = wp.zeros(n, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu")
    replays = Replays()
    replays.get(_affine, n, [x, 1.5, wp.vec3(0.25, 0.0, 0.5)], [y], device="cpu").launch()  # recorded, loaded
    invoked = []
    plain = warp_context.invoke
    monkeypatch.setattr(warp_context, "invoke", lambda *a, **k: (invoked.append(1), plain(*a, **k)))
    xs = x.numpy()
    for a, v, out, dim in [(1.5, (0.25, 0.0, 0.5), y, n), (-3.0, (0.25, 0.0, 0.5), y, n), (-3.0, (2.0, 0.0, -1.0), y, n),
                           (0.5, (2.0, 0.0, -1.0), y2, n), (0.5, (2.0, 0.0, -1.0), y2, 3000)]:
        out.zero_()
        rec = replays.get(_affine, dim, [x, a, wp.vec3(*v)], [out], device="cpu")
        assert len(rec.cmds) == threads
        for _ in range(2):
            rec.launch()
        expect = np.zeros(n, np.float32)
        expect[:dim] = np.float32(a) * xs[:dim] + np.float32(v[0]) - np.float32(v[2])
        assert np.array_equal(out.numpy(), expect)
    assert not invoked  # every replay ran prepared
    core_launch.PREPARED_REPLAY = False
    try:
        replays.get(_affine, n, [x, 0.5, wp.vec3(0.0)], [y], device="cpu").launch()
    finally:
        core_launch.PREPARED_REPLAY = True
    assert len(invoked) == threads  # the switch (benchmarks/dfsph_step_profile.py) goes back through Warp's launch


def test_replays_of_an_unverified_warp_go_through_its_launch(monkeypatch):
    """On a Warp release whose CPU launch ABI was not verified (``PREPARED_WARP_VERSIONS``), a replay is Warp's own
    ``cmd.launch`` (never the prepared struct), and computes what the NumPy oracle says after a changed scalar."""
    monkeypatch.setattr(wp, "__version__", "9.0.0")
    n = 1000
    x = wp.array(np.arange(n, dtype=np.float32), dtype=float, device="cpu")
    y = wp.zeros(n, dtype=float, device="cpu")
    replays = Replays()
    for a in (2.0, -1.0):
        rec = replays.get(_affine, n, [x, a, wp.vec3(1.0, 0.0, 0.5)], [y], device="cpu")
        rec.launch()
        assert all(run == cmd.launch for run, cmd in zip(rec.runs(), rec.cmds))
        assert np.array_equal(y.numpy(), np.float32(a) * np.arange(n, dtype=np.float32) + np.float32(0.5))
