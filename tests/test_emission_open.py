"""The container's open faces as an outflow (``container.open``, docs/emitters.md): no wall particles on an
open face, fluid past it removed at the next frame's start by the sinks' gather (and nothing else removed),
mass bookkeeping every frame, and bad input refused before anything runs.
"""
import numpy as np
import pytest

from warp_sph.cli import main as cli_main
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict
from warp_sph.scene.meshes import box_surface

OPEN = {
    "name": "open", "particle_radius": 0.025, "duration": 1.0, "fps": 24.0, "solver": "pbf",
    "container": {"min": [0.0, 0.0, 0.0], "max": [0.6, 0.3, 0.5], "open": ["+x"]},
    "fluid": [{"min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.3], "velocity": [1.5, 0.0, 0.0]}],
    "output": {"surface": False, "usd": False},
}


def test_open_face_has_no_wall_particles_but_keeps_its_edges():
    """box_surface without the +x face: its interior points are gone, the edges it shares with the closed
    faces stay, and those edge points take their normals from the closed faces only."""
    lo, hi, d = (0.0, 0.0, 0.0), (0.6, 0.3, 0.5), 0.05
    full, _ = box_surface(lo, hi, d, inward=True)
    p, n = box_surface(lo, hi, d, inward=True, open_faces=[(0, 1)])
    on_face = np.isclose(full[:, 0], 0.6)
    edge = on_face & (np.isclose(full[:, 1], 0.0) | np.isclose(full[:, 1], 0.3) | np.isclose(full[:, 2], 0.0)
                      | np.isclose(full[:, 2], 0.5))
    assert len(p) == len(full) - int((on_face & ~edge).sum())
    kept = np.isclose(p[:, 0], 0.6)
    assert kept.sum() == edge.sum() and np.all(n[kept, 0] == 0.0)  # no normal component through the open face
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_outflow_removes_what_crossed_the_open_face_only(device):
    """A block thrown at the open +x face: every frame, the particles removed at its start are exactly those
    past the face at the end of the last frame (none through the closed faces), initial - removed = active,
    ids stay unique, and the watchdog lets the leaving fluid go."""
    sim = Simulation(scene_from_dict(OPEN, source="open.toml"), device=device)
    n0 = sim.model.fluid_count
    hi = float(sim.model.container_hi[0])
    assert sim.model.boundary_count < len(box_surface((0, 0, 0), (0.6, 0.3, 0.5), sim.model.spacing, True)[0])
    ids = sim.get_field("particle_id")
    past = np.zeros(n0, dtype=bool)
    removed_total = 0
    for _ in range(10):
        s = sim.advance_frame()
        now = sim.get_field("particle_id")
        gone = set(ids.tolist()) - set(now.tolist())
        assert gone == set(ids[past].tolist())  # removed at this frame's start: past the face at the last end
        removed_total += len(gone)
        assert s.flow["removed"] == removed_total and s.flow["particles"] == n0 - removed_total == len(now)
        assert len(np.unique(now)) == len(now)
        x = sim.fields["particle_x"].numpy()  # local coordinates, as the removal compares them
        past = x[:, 0] >= hi
        ids = now
    assert removed_total > 0.2 * n0


@pytest.mark.parametrize("container,words", [
    ({"min": [0.0, 0.0, 0.0], "max": [0.6, 0.3, 0.5], "open": ["+w"]}, "container.open: expected a list of strings"),
    ({"min": [0.0, 0.0, 0.0], "max": [0.6, 0.3, 0.5], "open": "+x"}, "container.open"),
])
def test_bad_open_faces_one_line_exit_2(tmp_path, capsys, container, words):
    def toml_value(v):
        if isinstance(v, str):
            return f'"{v}"'
        return "[" + ", ".join(toml_value(x) for x in v) + "]" if isinstance(v, list) else repr(v)

    path = tmp_path / "bad.toml"
    path.write_text("particle_radius = 0.025\n[container]\n" + "".join(f"{k} = {toml_value(v)}\n" for k, v in
                                                                       container.items())
                    + "[[fluid]]\nmin = [0.0, 0.0, 0.0]\nmax = [0.3, 0.3, 0.3]\n")
    out = tmp_path / "out"
    assert cli_main(["run", str(path), "--out", str(out), "--frames", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1 and "bad.toml" in err
    assert not out.exists()
