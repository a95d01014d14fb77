"""Where DFSPH's search time goes, and what the search skin (``dfsph.search_skin``) does to it.

    python -m benchmarks.dfsph_search_profile 13 30            # side by side at one state (process CPU)
    python -m benchmarks.dfsph_search_profile 13 30 wall       # the same, wall-clock time
    python -m benchmarks.dfsph_search_profile 13 rate 0.5 1.0  # list builds over a run
    python -m benchmarks.dfsph_search_profile 13 walls 3       # whole runs: wall lists against the wall walk
    python -m benchmarks.dfsph_search_profile 5 20 particle_radius=0.0125  # key=value: scene overrides

Side by side: runs the default dam break (no output) for that many frames, then at that state times
(process CPU, one thread: ``WARP_SPH_CPU_THREADS=1``; or wall-clock time with "wall"; the first round
not counted) the given number of rounds of the cell sort and the search of each variant, in turn
(medians over the rounds): the per-step search (cells of H_s; the static walls from their sub-cell
lists, ``WALL_SUBCELLS``), the lists with 1, 2 and 4 sub-cells per cell, the per-step wall walk, cells
of H_s / 2, and the skin at 0.5 d and 1 d with the lists rebuilt and reused; each kernel launch of the
search (launched one by one, not through ``run_loop``: bitwise the same); the fluid walk's and the
walls' candidates per particle (counted in NumPy) and the wall lists' memory. "rate": the same run for
each skin, counting list builds against searches and the particles' displacement per step [d]. One JSON
object on stdout. Wrap it in ``flock /tmp/warp_sph_bench.lock`` on a shared machine. A diagnostic beside
``warp-sph bench splishsplash``.
"""
from __future__ import annotations

import collections
import json
import os
import statistics
import sys
import time


#: scene overrides of every run (key=value arguments on the command line, e.g. particle_radius=0.0125)
SCENE_SET: list[str] = []


def _scene(over: list[str]):
    from warp_sph.scene import load_scene

    return load_scene("dam_break", overrides=["output.usd=false", "output.surface=false"] + SCENE_SET + over)


def candidates(grid, x, radius: float, mask=None) -> tuple[float, float]:
    """The walk's candidates per query point x (points in the trimmed rows of ``row_points`` over
    ``grid``, a built ``CellGrid``), counted in NumPy, the share of queries that walk (not in a cell
    whose ``mask`` is 0, as the boundary walk skips them) and the rows each walking query visits."""
    import numpy as np

    x = np.asarray(x, dtype=np.float64)
    lo = np.array([grid.lo[0], grid.lo[1], grid.lo[2]])
    dims = np.array([grid.dims[0], grid.dims[1], grid.dims[2]])
    start = grid.cell_start.numpy()
    q = (x - lo) * grid.inv_cell_size
    qr = radius * grid.inv_cell_size
    walks = np.ones(len(x), dtype=bool)
    if mask is not None:
        c = np.clip(np.floor(q).astype(int), 0, dims - 1)
        walks = mask.numpy()[c[:, 0] + dims[0] * (c[:, 1] + dims[1] * c[:, 2])] != 0

    def rows(c):  # first and last row of each query along one axis (``cell_rows``)
        return (np.clip(np.floor(q[:, c] - qr), 0, dims[c] - 1).astype(int),
                np.clip(np.floor(q[:, c] + qr), 0, dims[c] - 1).astype(int))

    def distance(c, cell):  # from q to the row's cells along one axis (border rows reach to infinity)
        return (np.where((cell > 0) & (q[:, c] < cell), cell - q[:, c], 0.0)
                + np.where((cell < dims[c] - 1) & (q[:, c] > cell + 1), q[:, c] - cell - 1, 0.0))

    (y0, y1), (z0, z1) = rows(1), rows(2)
    total = visited = 0
    for oz in range(int(np.ceil(2 * qr)) + 2):
        for oy in range(int(np.ceil(2 * qr)) + 2):
            z, y = z0 + oz, y0 + oy
            dy, dz = distance(1, y), distance(2, z)
            rest = qr * qr - dy * dy - dz * dz
            ok = walks & (z <= z1) & (y <= y1) & (rest > 0)
            xr = np.sqrt(np.maximum(rest, 0.0))
            row = dims[0] * (np.minimum(y, dims[1] - 1) + dims[1] * np.minimum(z, dims[2] - 1))
            x0 = np.clip(np.floor(q[:, 0] - xr).astype(int), 0, dims[0] - 1)
            x1 = np.clip(np.floor(q[:, 0] + xr).astype(int), 0, dims[0] - 1)
            total += np.where(ok, start[row + x1 + 1] - start[row + x0], 0).sum()
            visited += ok.sum()
    walking = max(1, int(walks.sum()))
    return round(float(total) / len(x), 1), round(float(walks.mean()), 3), round(float(visited) / walking, 1)


def walk_counts(sim) -> dict:
    """Candidates per fluid particle of the fluid walk and of the static wall walk (and the share of
    particles that walk the wall grid) on the grids the search just used."""
    nl, n = sim.fields["neighbor_lists"], sim.model.fluid_count
    x = nl.fluid_cells.sorted_x.numpy()[:n]
    fluid, _, rows = candidates(nl.fluid_cells, x, nl.search_radius)
    out = {"fluid walk candidates": fluid, "fluid walk rows": rows}
    walls = getattr(sim.solver, "_walls", None)
    if walls is not None:  # the static walls' sub-cell lists: the list of each particle's sub-cell
        import numpy as np

        lo = np.array([walls.cells.lo[a] for a in range(3)])
        dims = np.array([walls.dims[a] for a in range(3)])
        s = np.clip(np.floor((x - lo) * walls.inv_size).astype(int), 0, dims - 1)
        length = np.diff(walls.start.numpy())[s[:, 0] + dims[0] * (s[:, 1] + dims[1] * s[:, 2])]
        out.update({"wall list candidates": round(float(length.mean()), 1),
                    "share with a wall list": round(float((length > 0).mean()), 3),
                    "wall list bytes per wall particle": round(walls.nbytes / walls.cells.count, 1),
                    "wall list entries per wall particle": round(walls.entries / walls.cells.count, 1)})
    elif nl.boundary_cells is not None:
        per_particle, share, _ = candidates(nl.boundary_cells, x, nl.search_radius, nl.boundary_mask)
        out.update({"wall walk candidates": per_particle, "share walking the walls": share})
    return out


def side_by_side(frames: int, rounds: int, clock=time.process_time) -> dict:
    import warp_sph.methods.solvers.dfsph_search as host
    import warp_sph.neighbors.wall_reach as walls
    import warp_sph.neighbors.cell_lists as cell_lists
    from warp_sph.run.simulation import Simulation

    sim0 = Simulation(_scene([]))
    for _ in range(frames):
        sim0.advance_frame()
    x, v = sim0.get_field("particle_x"), sim0.get_field("particle_v")

    subcells = walls.WALL_SUBCELLS

    def variant(over, cells_per_radius=1, wall_subcells=subcells):
        cell_lists.simulation_neighbor_lists.__defaults__ = (0.0, cells_per_radius)
        walls.WALL_SUBCELLS = wall_subcells
        try:
            sim = Simulation(_scene(over))
        finally:
            cell_lists.simulation_neighbor_lists.__defaults__ = (0.0, 1)
            walls.WALL_SUBCELLS = subcells
        sim.set_field("particle_x", x)
        sim.set_field("particle_v", v)
        return sim

    variants = {f"per-step search (wall lists, {subcells} sub-cells)": sim0}
    variants.update({f"wall lists, {k} sub-cells": variant([], wall_subcells=k) for k in (1, 2, 4) if k != subcells})
    variants.update({"wall walk": variant([], wall_subcells=0)})
    variants.update({"cells H_s/2": variant([], 2)})
    variants.update({"skin 0.5 d": variant(["dfsph.search_skin=0.5"]), "skin 1 d": variant(["dfsph.search_skin=1.0"])})
    call_s, kernel_s = collections.defaultdict(list), collections.defaultdict(list)
    plain_launch = host.launch
    current = [""]

    def timed_launch(kernel, dim, *args, **kw):
        t = clock()
        plain_launch(kernel, dim, *args, **kw)
        kernel_s[current[0] + ": " + getattr(kernel, "key", str(kernel)).split("__")[0]].append(clock() - t)

    host.launch = timed_launch
    for sim in variants.values():
        sim.solver.sweep_loop = False  # each kernel through ``launch`` (bitwise the run_loop path), timed
    try:
        for r in range(rounds + 1):
            for name, sim in variants.items():
                current[0] = name
                nl, solver = sim.fields["neighbor_lists"], sim.solver
                with sim.in_cell_order():
                    t0 = clock()
                    nl.sort(sim.fields["particle_x"])
                    t1 = clock()
                    if solver.skin:
                        solver._built = None  # the lists rebuilt
                    solver.search(3e-3)
                    t2 = clock()
                    if solver.skin:
                        solver.search(3e-3)  # lists reused
                    t3 = clock()
                if r == 0:
                    kernel_s.clear()
                    continue
                call_s[name + ": sort"].append(t1 - t0)
                call_s[name + ": search" + (", lists built" if solver.skin else "")].append(t2 - t1)
                if solver.skin:
                    call_s[name + ": search, lists reused"].append(t3 - t2)
    finally:
        host.launch = plain_launch
    n = sim0.model.fluid_count
    return {"frames": frames, "rounds": rounds, "set": SCENE_SET, "fluid": n, "boundary": sim0.model.boundary_count,
            "threads": os.environ.get("WARP_SPH_CPU_THREADS", "all"), "load": os.getloadavg(),
            "candidates per fluid particle": {name: walk_counts(sim) for name, sim in variants.items()
                                              if not sim.solver.skin},
            "ms per call (median)": {k: round(1e3 * statistics.median(v), 3) for k, v in call_s.items()},
            "kernel ms per call (median)": {k: round(1e3 * statistics.median(v), 3) for k, v in kernel_s.items()},
            "fluid pairs per particle (j != i, < H_s)": round(float(sim0.fields["dfsph_pairs"].count.numpy()[:n].mean()), 2),
            "wall particles within H_s per walking particle": round(float(
                sim0.fields["neighbor_lists"].boundary.count.numpy()[:n].sum()
                / max(1.0, walk_counts(variants["wall walk"]).get("share walking the walls", 0.0) * n)), 2),
            "wall neighbours per particle": round(float(sim0.fields["neighbor_lists"].boundary.count.numpy()[:n].mean()), 2)}


def rebuild_rate(frames: int, skins: list[float]) -> dict:
    import numpy as np

    from warp_sph.run.simulation import Simulation

    out = {}
    for skin in skins:
        sim = Simulation(_scene([f"dfsph.search_skin={skin}"]))
        searches = [0]
        moved = []
        stages = {s.name: s for s in sim.graph.stages}
        plain_search, plain_integrate = stages["density"].run, stages["integrate"].run

        def search(s, dt):
            searches[0] += 1
            plain_search(s, dt)

        def integrate(s, dt):
            n = sim.model.fluid_count
            x0 = s.fields["particle_x"].numpy()[:n].copy()
            plain_integrate(s, dt)
            moved.append(np.linalg.norm(s.fields["particle_x"].numpy()[:n] - x0, axis=1) / sim.model.spacing)

        stages["density"].run, stages["integrate"].run = search, integrate
        builds0, t = sim.solver.list_builds, time.process_time()
        for _ in range(frames):
            sim.advance_frame()
        out[f"skin {skin:g} d"] = {
            "searches": searches[0], "list builds": sim.solver.list_builds - builds0, "cpu s": round(time.process_time() - t, 2),
            "mean displacement per step [d]": round(float(np.mean([m.mean() for m in moved])), 4),
            "largest displacement per step [d], mean over steps": round(float(np.mean([m.max() for m in moved])), 4)}
    return {"frames": frames, "runs": out}


def walls_runs(frames: int, repeats: int) -> dict:
    """Whole runs of the dam break (``frames`` frames, no output) with the static walls from their sub-cell
    lists (``WALL_SUBCELLS``) and with the per-step wall walk (0), ``repeats`` times in turns: process CPU
    and wall seconds of each run (the first frames' kernel compiles are outside: a run of one frame first)."""
    import warp_sph.neighbors.wall_reach as walls
    from warp_sph.run.simulation import Simulation

    subcells = walls.WALL_SUBCELLS
    runs = collections.defaultdict(lambda: collections.defaultdict(list))
    try:
        for r in range(repeats + 1):
            for k in (subcells, 0):
                walls.WALL_SUBCELLS = k
                sim = Simulation(_scene([]))
                cpu, wall = time.process_time(), time.perf_counter()
                for _ in range(frames if r else 1):
                    sim.advance_frame()
                if r:
                    name = f"wall lists, {k} sub-cells" if k else "wall walk"
                    runs[name]["cpu s"].append(round(time.process_time() - cpu, 3))
                    runs[name]["wall s"].append(round(time.perf_counter() - wall, 3))
                    runs[name]["steps"].append(int(sim.state.step))
    finally:
        walls.WALL_SUBCELLS = subcells
    return {"frames": frames, "repeats": repeats, "threads": os.environ.get("WARP_SPH_CPU_THREADS", "all"),
            "load": os.getloadavg(), "runs": {k: dict(v) for k, v in runs.items()},
            "median cpu s": {k: statistics.median(v["cpu s"]) for k, v in runs.items()},
            "median wall s": {k: statistics.median(v["wall s"]) for k, v in runs.items()}}


def main(argv: list[str]) -> None:
    SCENE_SET[:] = [a for a in argv if "=" in a]
    argv = [a for a in argv if "=" not in a]
    frames = int(argv[0])
    if len(argv) > 1 and argv[1] == "rate":
        result = rebuild_rate(frames, [float(a) for a in argv[2:]] or [0.5, 1.0])
    elif len(argv) > 1 and argv[1] == "walls":
        result = walls_runs(frames, int(argv[2]) if len(argv) > 2 else 3)
    else:
        wall = len(argv) > 2 and argv[2] == "wall"
        clock = time.perf_counter if wall else time.process_time
        result = side_by_side(frames, int(argv[1]) if len(argv) > 1 else 30, clock)
        result["clock"] = "wall" if wall else "process CPU"
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
