"""Argument types and name checks of ``warp-sph bench`` (``runner.py``'s parser, ``commands.py``).

Each refuses a bad value with one line before any case runs: argparse's error (exit status 2) for the
types, ``WarpSphError`` (the CLI's exit status 2) for the checks that need the registry.
"""
from __future__ import annotations

import argparse
import math



def number(kind: type, minimum: float, strict: bool = True, many: bool = False):
    """argparse type: a number of ``kind`` (int or float) above ``minimum`` (or at it, ``strict=False``),
    finite; ``many``: comma-separated such numbers, kept as the text the commands split. A bad value is
    argparse's one-line error, exit status 2."""
    what = f"{'comma-separated ' if many else 'an '}{'integer' if kind is int else 'number'}{'s' if many else ''} " \
           f"{'>' if strict else '>='} {minimum:g}"

    def check(text: str):
        try:
            values = [kind(v.strip()) for v in (text.split(",") if many else [text]) if v.strip()]
            ok = bool(values) and all(math.isfinite(v) and (v > minimum if strict else v >= minimum) for v in values)
        except ValueError:
            ok = False
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return text if many else values[0]

    return check


positive_int = number(int, 0)
positive_float = number(float, 0)
positive_ints = number(int, 0, many=True)
positive_floats = number(float, 0, many=True)
nonnegative_floats = number(float, 0, strict=False, many=True)


def whitewater_rates(text: str) -> list[str]:
    """argparse type of ``bench whitewater --rates``: comma-separated names of ``whitewater.RATES``."""
    from .whitewater import RATES

    names = [r.strip() for r in text.split(",") if r.strip()]
    if not names or any(r not in RATES for r in names):
        raise argparse.ArgumentTypeError(f"expected comma-separated rate sets of {', '.join(RATES)}, got {text!r}")
    return names


def check_names(option: str, text: str | None, known) -> None:
    """Refuse unknown scene or solver names before any case runs (one line, exit status 2)."""
    from warp_sph.core.errors import WarpSphError

    if not text:
        return
    bad = [v.strip() for v in text.split(",") if v.strip() and v.strip() not in known]
    if bad:
        raise WarpSphError(f"bench: {option} {text!r}: unknown {', '.join(map(repr, bad))}; "
                           f"expected some of {', '.join(known)}")


def parse_resolutions(text: str) -> list[tuple[float, float]]:
    """'0.025:1.0,0.0125:0.3' -> [(0.025, 1.0), (0.0125, 0.3)]: particle radius [m] and simulated seconds."""
    from warp_sph.core.errors import WarpSphError

    out = []
    for item in [v.strip() for v in text.split(",") if v.strip()]:
        r, sep, d = item.partition(":")
        try:
            out.append((float(r), float(d) if sep else 1.0))
        except ValueError:
            raise WarpSphError(f"bench splishsplash: --resolutions {text!r}: expected RADIUS:SECONDS,... "
                               "e.g. 0.025:1.0,0.0125:0.3") from None
        if out[-1][0] <= 0 or out[-1][1] <= 0:
            raise WarpSphError(f"bench splishsplash: --resolutions {text!r}: radius and seconds must be > 0")
    return out
