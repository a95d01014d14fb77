"""Whitewater's emission pass runs one thread per new particle (``kernels/whitewater.emit_kernel``): each
thread finds the fluid slot its particle belongs to by a binary search of the counts' exclusive scan
(``emitting_slot``), checked here against NumPy's searchsorted on counts with runs of zeros."""
import numpy as np
import warp as wp

from warp_sph.kernels.whitewater import emitting_slot


@wp.kernel(enable_backward=False)
def _slots(n: int, offset: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    k = wp.tid()
    out[k] = emitting_slot(k, n, offset)


def test_emitting_slot_matches_searchsorted():
    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 1000):
        counts = rng.integers(0, 4, size=n) * (rng.random(n) < 0.3)  # mostly zeros
        counts[-1] = 2  # a last slot that emits (its threads end the range)
        if n > 2:
            counts[0] = 0  # and a first that does not
        offset = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
        total = int(counts.sum())
        out = wp.zeros(total, dtype=wp.int32, device="cpu")
        wp.launch(_slots, total, inputs=[n, wp.array(offset, dtype=wp.int32, device="cpu")], outputs=[out],
                  device="cpu")
        want = np.searchsorted(offset, np.arange(total), side="right") - 1
        got = out.numpy()
        assert np.array_equal(got, want)
        assert np.all(counts[got] > 0)  # every new particle belongs to a slot that generates
        assert np.array_equal(np.bincount(got, minlength=n), counts)  # each slot gets exactly its count


def test_whitewater_with_an_emitter_sizes_its_arrays_for_the_capacity():
    """Whitewater with [[emitters]]: its per-fluid-slot arrays had the initial count, and the passes over the
    grown count wrote past them (heap corruption: 'free(): invalid next size', exit 134, at the faucet's exit).
    Now every per-slot array holds the capacity, and the jet's new particles generate spray."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import scene_from_dict

    scene = scene_from_dict({
        "name": "jet", "particle_radius": 0.03, "duration": 1.0, "fps": 25.0,
        "container": {"min": [0.0, 0.0, 0.0], "max": [0.6, 0.6, 0.6]},
        "fluid": [{"min": [0.0, 0.0, 0.0], "max": [0.6, 0.6, 0.12]}],
        "emitters": [{"shape": "circle", "position": [0.3, 0.3, 0.5], "direction": [0.0, 0.0, -1.0],
                      "radius": 0.06, "speed": 1.5}],
        "whitewater": {"kinetic_energy_min": 0.5, "trapped_air_rate": 4000.0, "wave_crest_rate": 50000.0},
        "output": {"surface": False, "usd": False}}, source="jet.toml")
    sim = Simulation(scene, device="cpu")
    ww, n0 = sim.whitewater, sim.model.fluid_count
    for _ in range(8):
        sim.advance_frame()
    assert sim.model.fluid_count > n0  # the jet grew the count past the arrays' old size
    cap = sim.model.capacity
    for a in (ww._generate, ww._generate_offset, ww.normal, ww._trapped, ww._state, ww._need, ww.potential):
        assert a.shape[0] == cap
    assert ww.generated > 0
