"""The particle counts ``warp-sph plan`` and the memory pre-flight estimate before sampling
(``run.memory.estimate_particle_counts``): a box fluid block's count is the lattice the sampler places, the wall gap
included (issue 37: the coarse hydrostatic tank was estimated at 300 fluid particles where 125 were sampled). Oracle:
the sampled scene (NumPy sampling, no kernel runs)."""
from __future__ import annotations

import pytest

from warp_sph.run.memory import estimate_particle_counts
from warp_sph.scene import load_scene
from warp_sph.scene.sampling import sample_scene


@pytest.mark.parametrize("name, radius", [("hydrostatic", 0.0426), ("hydrostatic", 0.025), ("hydrostatic", 0.0194),
                                          ("dam_break", 0.0426), ("drop_into_pool", 0.025)])
def test_a_box_blocks_estimate_is_its_sampled_count(name, radius):
    scene = load_scene(name, overrides=[f"particle_radius={radius}"])
    fluid, boundary = estimate_particle_counts(scene)
    sampled = sample_scene(scene)
    assert fluid == sampled.fluid_count
    assert boundary == pytest.approx(sampled.boundary_count, rel=0.05)   # the walls: area / d^2


@pytest.mark.parametrize("fluid_box", [
    ("[0.2, 0.2, 0.2]", "[0.6, 0.5, 0.45]"),      # inside, clear of the walls: volume / d^3
    ("[0.0, 0.1, 0.0]", "[0.37, 0.5, 0.3]"),      # against the floor and one wall: clipped there only
    ("[0.0, 0.0, 0.0]", "[1.0, 0.33, 0.61]"),     # wall to wall in x: centred between them
])
def test_a_clipped_or_free_box_block(tmp_path, fluid_box):
    lo, hi = fluid_box
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nparticle_radius = 0.02\nduration = 0.1\n[container]\nmin = [0.0, 0.0, 0.0]\n'
                    f'max = [1.0, 0.8, 1.0]\n[[fluid]]\nmin = {lo}\nmax = {hi}\n[output]\nusd = false\n')
    scene = load_scene(str(path))
    assert estimate_particle_counts(scene)[0] == sample_scene(scene).fluid_count
