"""``Param``: the declaration of one scene key (type, unit, default, valid range, meaning) and how it
reads in words: in an error message (``expected``), in the Markdown tables (``default_text``, ``valid_text``).

The rows themselves, core and each method's, are ``parameters.py`` (which re-exports these names).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

TABLE_KINDS = ("table", "tables", "table_or_false")


class _Required:
    def __repr__(self):
        return "required"


REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Param:
    """Definition of one scene parameter.

    path: key path; ``a.b`` for a key of table ``a``, ``a[].b`` for a key of array of tables ``a``.
    kind: "float", "int", "bool", "str", "vec3", "str_list", "table", "tables" or "table_or_false".
    unit: SI unit, "-" for dimensionless.
    default: value when absent (REQUIRED: must be given; None: optional, meaning in ``doc``).
    gt/ge/lt/le: numeric bounds (for a vec3: bounds of its length); choices: allowed strings.
    shapes: for fluid/obstacle keys, the shapes that use the key (None: every shape).
    """

    path: str
    kind: str
    unit: str
    default: Any
    doc: str
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    shapes: tuple[str, ...] | None = None
    default_text: str | None = None

    @property
    def section(self) -> str:
        return self.path.rpartition(".")[0]

    @property
    def key(self) -> str:
        return self.path.rpartition(".")[2]

    def expected(self) -> str:
        """What a valid value looks like, in words (used in error messages and the docs)."""
        if self.choices is not None:
            opts = ", ".join(repr(c) for c in self.choices)
            return f"a list of strings from {opts}" if self.kind == "str_list" else f"one of {opts}"
        base = {
            "float": "a finite number",
            "int": "an integer",
            "bool": "true or false",
            "str": "a string",
            "vec3": "a list of 3 finite numbers",
            "table": "a table",
            "tables": "an array of tables ([[...]])",
            "table_or_false": "a table or false",
        }[self.kind]
        bounds = self.range_text()
        if bounds and self.kind == "vec3":
            return f"{base} of length {bounds}"
        return f"{base} {bounds}" if bounds else base

    def in_range(self, value: float) -> bool:
        """Whether the number ``value`` (a vec3's length) is finite and within the bounds."""
        v = float(value)
        return (math.isfinite(v) and (self.gt is None or v > self.gt) and (self.ge is None or v >= self.ge)
                and (self.lt is None or v < self.lt) and (self.le is None or v <= self.le))

    def range_text(self) -> str:
        parts = []
        if self.gt is not None:
            parts.append(f"> {self.gt:g}")
        if self.ge is not None:
            parts.append(f">= {self.ge:g}")
        if self.lt is not None:
            parts.append(f"< {self.lt:g}")
        if self.le is not None:
            parts.append(f"<= {self.le:g}")
        return " and ".join(parts)



#: a kind as the Markdown tables name it
KIND_NAMES = {"float": "float", "int": "int", "bool": "bool", "str": "string", "vec3": "[x, y, z]",
              "str_list": "list of strings", "table": "table", "tables": "array of tables",
              "table_or_false": "table or false"}


def default_text(p: Param) -> str:
    """The default as the tables print it ("" for a table, "required", a TOML-like value)."""
    if p.default_text is not None:
        return p.default_text
    if p.default is REQUIRED:
        return "required"
    if p.kind in ("table", "tables"):
        return ""
    d = p.default
    if isinstance(d, bool):
        return "true" if d else "false"
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, (list, tuple)):
        return "[" + ", ".join(f'"{x}"' if isinstance(x, str) else f"{x:g}" for x in d) + "]"
    if isinstance(d, float):
        return f"{d:g}"
    return str(d)


def valid_text(p: Param, vec3_length: bool = False) -> str:
    """The valid values as the tables print it: the choices or the bounds (``vec3_length``: "length <= 1000" for
    a vec3's bounds), then the shapes that use the key."""
    if p.choices is not None:
        valid = ", ".join(f'"{c}"' for c in p.choices)
    else:
        valid = p.range_text()
        if valid and vec3_length and p.kind == "vec3":
            valid = f"length {valid}"
    if p.shapes is not None:
        valid = (valid + "; " if valid else "") + f"shape {', '.join(p.shapes)}"
    return valid
