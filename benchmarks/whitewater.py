"""``warp-sph bench whitewater``: what whitewater (``[whitewater]``, docs/whitewater.md) costs per step.

The same splash scene with whitewater off and on, the latter at each set of generation rates asked for
(``RATES``: the project's defaults and SPlisHSPlasH's FoamGenerator rates, 8 times as many particles);
each variant runs ``repeats`` times, in turn, each in a fresh process. The measure is the process CPU
time per substep of the frames (all threads; load-independent work), the fastest run of each variant;
the whitewater stage's share of the stage wall times is reported beside it. The goal (issue #30):
whitewater costs at most 15 % of the step.
"""
from __future__ import annotations

#: the issue's goal: with whitewater on, a step costs at most this much more
GOAL = 0.15
#: generation rate sets (trapped air, wave crest) [1/s] by name; None: the scene's (the parameter defaults)
RATES = {"default": None, "splishsplash": (4000.0, 50000.0)}
_KEYS = ("whitewater.trapped_air_rate", "whitewater.wave_crest_rate")


def effective_rates(name: str, overrides=()) -> tuple[float, float]:
    """(k_ta, k_wc) [1/s] of rate set ``name`` after the user's ``--set`` overrides (these win)."""
    from warp_sph.scene.parameters import parameter

    rates = list(RATES[name] or (parameter(k).default for k in _KEYS))
    for item in overrides:
        key, _, value = item.partition("=")
        if key in _KEYS:
            rates[_KEYS.index(key)] = float(value)
    return float(rates[0]), float(rates[1])


def specs(scene_name: str, frames: int, repeats: int, device=None, overrides=(), rates=tuple(RATES)) -> list:
    """RunSpecs: (on at each rate set, off) x repeats, in turn."""
    from .cases import RunSpec

    unknown = [r for r in rates if r not in RATES]
    if unknown:
        raise ValueError(f"bench whitewater: unknown rate set {unknown[0]!r}; expected one of {', '.join(RATES)}")
    variants = [("on", r, [f"{k}={v:g}" for k, v in zip(_KEYS, RATES[r] or ())]) for r in rates]
    out = []
    for k in range(max(1, int(repeats))):
        # "off" says so: a --set whitewater.<key> alone would create the table and turn whitewater on
        for variant, rate, rate_set in (*variants, ("off", None, [])):
            extra = ["whitewater.enabled=true"] if variant == "on" else ["whitewater.enabled=false"]
            params = {"scene": scene_name, "variant": variant, "repeat": k + 1}
            if rate:
                ta, wc = effective_rates(rate, overrides)
                params.update(rates=rate, trapped_air_rate=ta, wave_crest_rate=wc)
            out.append(RunSpec(scene=scene_name, overrides=["output.usd=false", *rate_set, *overrides, *extra],
                               frames=frames, device=device, kind="whitewater", name="whitewater", params=params))
    return out


def cpu_ms_per_step(record: dict) -> float | None:
    m = record.get("metrics") or {}
    if not m.get("steps") or m.get("cpu_seconds") is None:
        return None
    return 1e3 * m["cpu_seconds"] / m["steps"]


def stage_share(record: dict) -> float | None:
    """The whitewater stage's share of the summed stage wall times, first calls excluded."""
    rows = record.get("stage_times") or []
    steady = {r["stage"]: r["seconds"] - r["first_call_seconds"] for r in rows}
    total = sum(steady.values())
    return steady.get("whitewater", 0.0) / total if total > 0 else None


def _rates_of(record: dict) -> str | None:
    """The rate set of an "on" record; records made before the rate sets count as "default" unless their
    overrides set a rate."""
    p = record.get("params") or {}
    if "rates" in p:
        return p["rates"]
    overrides = (record.get("spec") or {}).get("overrides") or []
    return "custom" if any(o.partition("=")[0] in _KEYS for o in overrides) else "default"


def summaries(records: list[dict]) -> list[dict]:
    """Per rate set: the fastest CPU ms per step on and off (off shared), the extra cost of whitewater."""
    best_off, on = None, {}
    for r in records:
        ms = cpu_ms_per_step(r)
        p = r.get("params") or {}
        if r.get("status") != "ok" or not ms:
            continue
        if p.get("variant") == "off":
            best_off = ms if best_off is None else min(best_off, ms)
        elif p.get("variant") == "on":
            key = _rates_of(r)
            if key not in on or ms < on[key][0]:
                on[key] = (ms, stage_share(r), p.get("trapped_air_rate"), p.get("wave_crest_rate"))
    if best_off is None:
        return []
    out = []
    for key, (ms, share, ta, wc) in on.items():
        extra = ms / best_off - 1.0
        out.append({"rates": key, "trapped_air_rate": ta, "wave_crest_rate": wc, "on_ms": ms, "off_ms": best_off,
                    "extra": extra, "stage_share": share, "goal": GOAL, "met": extra <= GOAL})
    return out


def summary(records: list[dict]) -> dict | None:
    """The first rate set's summary (``summaries``), None without an on and an off run."""
    s = summaries(records)
    return s[0] if s else None


def _rates_text(s: dict) -> str:
    if s.get("trapped_air_rate") is None:
        return f"rates {s['rates']}"
    return f"rates {s['rates']} (k_ta {s['trapped_air_rate']:g}, k_wc {s['wave_crest_rate']:g} 1/s)"


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench whitewater`` run."""
    if not records:
        return []
    lines = ["## Whitewater", ""] + head(records)
    scene = (records[0].get("params") or {}).get("scene", "?")
    lines += [f"Scene `{scene}` with `[whitewater]` on (at each set of generation rates: *default*, the project's; "
              "*splishsplash*, SPlisHSPlasH's FoamGenerator rates, 8 times as many particles) and off, each run in "
              "turn in a fresh process. *CPU ms/step*: process CPU time of the frames per substep (all threads); "
              "*stage share*: the whitewater stage's part of the stage wall times. The goal compares the fastest "
              "*CPU ms/step* of each variant.", ""]
    header = ["variant", "rates", "k_ta, k_wc [1/s]", "repeat", "status", "fluid N", "steps", "CPU ms/step",
              "stage share", "load (1 min)"]
    rows = []
    for r in records:
        p, m = r.get("params") or {}, r.get("metrics") or {}
        on = p.get("variant") == "on"
        share = stage_share(r) if on else None
        ks = f"{p['trapped_air_rate']:g}, {p['wave_crest_rate']:g}" if "trapped_air_rate" in p else "-"
        rows.append([p.get("variant", "?"), _rates_of(r) if on else "-", ks, fmt(p.get("repeat")),
                     r.get("status", "?"), fmt(r.get("fluid_particles")), fmt(m.get("steps")), fmt(cpu_ms_per_step(r)),
                     f"{100 * share:.1f} %" if share else "-",
                     fmt(((r.get("host") or {}).get("load_average") or [None])[0])])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    for s in summaries(records):
        lines += [f"Fastest, {_rates_text(s)}: {fmt(s['on_ms'])} CPU ms per step with whitewater, {fmt(s['off_ms'])} "
                  f"without: {100 * s['extra']:+.1f} % (goal: at most +{100 * GOAL:.0f} %; "
                  f"{'met' if s['met'] else 'not met'}).", ""]
    return lines
