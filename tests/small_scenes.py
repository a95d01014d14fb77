"""The small tank the solver stage tests share: a 0.6 x 0.5 x 0.5 m block in a 0.8 x 0.6 x 0.8 m box at
r = 0.05 m, outputs off; keyword tables merge into the defaults, other keywords replace them."""
from warp_sph.scene import scene_from_dict


def small_tank(name: str, solver: str = "dfsph", **kw):
    d = {
        "name": name,
        "particle_radius": 0.05,
        "solver": solver,
        "container": {"min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 0.8]},
        "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.6, 0.5, 0.5]}],
        "output": {"usd": False, "surface": False},
    }
    for k, v in kw.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            d[k] = {**d[k], **v}
        else:
            d[k] = v
    return scene_from_dict(d)


def stage(sim, name):
    """The step graph's stage called ``name``."""
    return next(s for s in sim.graph.stages if s.name == name)
