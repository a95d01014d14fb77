"""Gathers into and scatters out of cell order (host: ``warp_sph/neighbors/particle_order.py``; also the moving
boundary particles' volumes into their cell grid's order, ``warp_sph/neighbors/cell_lists.py``)."""
from typing import Any

import warp as wp


@wp.kernel(enable_backward=False)
def gather_by_order(
    tid_offset: int,
    # In:
    order: wp.array(dtype=wp.int32),
    source: wp.array(dtype=Any),
    # Out:
    target_out: wp.array(dtype=Any),
):
    """target[k] = source[order[k]] (into cell order)."""
    k = wp.tid() + tid_offset
    target_out[k] = source[order[k]]


@wp.kernel(enable_backward=False)
def scatter_by_order(
    tid_offset: int,
    # In:
    order: wp.array(dtype=wp.int32),
    source: wp.array(dtype=Any),
    # Out:
    target_out: wp.array(dtype=Any),
):
    """target[order[k]] = source[k] (back to the stable particle order)."""
    k = wp.tid() + tid_offset
    target_out[order[k]] = source[k]
