"""``warp-sph bench forces``: what each non-pressure force costs per particle-step, beside its solver.

For every solver and every registered force (``warp_sph.methods.registry.forces``, at its defaults), the
same scene runs with that force alone and with no force at all (a scene without forces runs the kernels
it ran before the family existed), ``repeats`` times, alternating, each in a fresh process. A force's
cost is the steady time of the stages the no-force graph does not have (its own stages and the shared
``apply_forces``), per particle-step; the step's cost is the sum over all stages. Per (solver, variant)
the fastest repeat counts (this machine's speed drifts with the load).
"""
from __future__ import annotations

NONE = "none"


def specs(scene: str, frames: int, repeats: int, solvers=None, forces=None, device=None, overrides=()) -> list:
    """RunSpecs: solver x (none, each force) x repeats, alternating within a repeat."""
    from warp_sph.methods import registry

    from .cases import RunSpec

    solvers = list(solvers or registry.solver_names())
    forces = list(forces or registry.force_names())
    out = []
    for k in range(max(1, int(repeats))):
        for solver in solvers:
            for force in [NONE] + forces:
                extra = [f"solver={solver}"] + ([] if force == NONE else [f'forces=[{{method = "{force}"}}]'])
                out.append(RunSpec(scene=scene, overrides=list(overrides) + extra, frames=frames, device=device,
                                   kind="forces", name="forces",
                                   params={"scene": scene, "solver": solver, "force": force, "repeat": k + 1}))
    return out


def _steady(row: dict) -> float:
    calls = row.get("calls", 0)
    return (row["seconds"] - row["first_call_seconds"]) / (calls - 1) if calls > 1 else 0.0


def costs(record: dict, bare_stages: set) -> dict | None:
    """{step_ns, force_ns} per particle-step of one record (None when it did not run or has no steps)."""
    rows = record.get("stage_times") or []
    n = record.get("fluid_particles") or 0
    if record.get("status") != "ok" or not rows or not n or max(r.get("calls", 0) for r in rows) < 2:
        return None
    step = sum(_steady(r) for r in rows)
    force = sum(_steady(r) for r in rows if r["stage"] not in bare_stages)
    return {"step_ns": 1e9 * step / n, "force_ns": 1e9 * force / n}


def summary(records: list[dict]) -> list[dict]:
    """Per (solver, force): the fastest repeat's step cost and the force's own cost [ns/particle-step], and
    the step cost of the same solver without forces."""
    bare: dict[str, set] = {}
    for r in records:
        p = r.get("params") or {}
        if p.get("force") == NONE and r.get("stage_times"):
            bare.setdefault(p["solver"], {s["stage"] for s in r["stage_times"]})
    best: dict[tuple, dict] = {}
    for r in records:
        p = r.get("params") or {}
        c = costs(r, bare.get(p.get("solver"), set()))
        key = (p.get("solver"), p.get("force"))
        if c and (key not in best or c["step_ns"] < best[key]["step_ns"]):
            best[key] = c
    out = []
    for (solver, force), c in best.items():
        if force == NONE:
            continue
        base = best.get((solver, NONE))
        out.append({"solver": solver, "force": force, "step_ns": c["step_ns"], "force_ns": c["force_ns"],
                    "bare_step_ns": base["step_ns"] if base else None})
    return out
