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
