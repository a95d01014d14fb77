"""Device arrays reused across calls (the surface passes' scratch space).

``ArrayPool.get(name, n, dtype)`` returns the array kept under ``name`` when it holds at least n rows,
else a new one of max(n, 1.5 x the old size) rows (so a slowly growing size reallocates O(log n)
times); its contents are undefined (``wp.empty``). Callers slice ``[:n]`` where the length matters.
"""
from __future__ import annotations

import warp as wp


class ArrayPool:
    """Named device arrays on one device, grown x1.5 when a call needs more rows."""

    def __init__(self, device):
        self.device = device
        self._arrays: dict[str, wp.array] = {}

    def get(self, name: str, n: int, dtype, width: int | None = None) -> wp.array:
        """An array of at least max(n, 1) rows of ``dtype`` (shape (rows, width) when width is given)."""
        n = max(int(n), 1)
        a = self._arrays.get(name)
        if a is None or a.shape[0] < n:
            cap = max(n, int(1.5 * (a.shape[0] if a is not None else 0)))
            shape = cap if width is None else (cap, width)
            a = wp.empty(shape, dtype=dtype, device=self.device)
            self._arrays[name] = a
        return a
