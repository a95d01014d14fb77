"""The one place host code launches kernels (returns early on empty ranges)."""
import warp as wp


def launch(kernel, dim: int, inputs, outputs=(), device=None) -> None:
    """wp.launch over ``dim`` threads; nothing happens when dim == 0."""
    if dim <= 0:
        return
    wp.launch(kernel, dim=dim, inputs=list(inputs), outputs=list(outputs), device=device)
