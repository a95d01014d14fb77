"""Registry of smoothing kernels by name, with support radius, default h and calibrated mass.

Device code: ``kernels/smoothing.py``. Here: the host descriptor of each kernel.

Default smoothing length per particle spacing d: all three kernels get the same support radius
H_s = 2d (cubic and quadric h = d, quintic h = 2d/3), so every kernel sees the same ~33
neighbours (the SPlisHSPlasH default support 4r = 2d) and a swap changes accuracy, not cost.
The particle mass is calibrated per kernel and h/d (report section 7.3): m = rho0 / sum_j W(x_ij)
over a perfect cubic lattice at spacing d, so an interior lattice particle reads exactly rho0.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .errors import SceneError
from ..kernels import smoothing as _dev
from .launch import launch


@dataclass(frozen=True)
class SmoothingKernel:
    """Host descriptor of one smoothing kernel.

    name: registry key ("cubic", "quintic", "quadric").
    support_per_h: support radius H_s as a multiple of the smoothing length h.
    default_h_per_spacing: default h / d, with d = 2 r the particle spacing.
    reference: where the formula comes from.
    """

    name: str
    support_per_h: float
    default_h_per_spacing: float
    reference: str

    def support_radius(self, h: float) -> float:
        """Support radius H_s = support_per_h * h [m]: the neighbour-search radius."""
        return self.support_per_h * h

    def default_smoothing_length(self, spacing: float) -> float:
        """Default smoothing length h [m] for particle spacing d [m]."""
        return self.default_h_per_spacing * spacing


SMOOTHING_KERNELS: dict[str, SmoothingKernel] = {
    "cubic": SmoothingKernel("cubic", 2.0, 1.0, "cubic spline, Monaghan & Lattanzio 1985 (Liu & Liu 2010)"),
    "quintic": SmoothingKernel("quintic", 3.0, 2.0 / 3.0, "quintic spline, Morris 1997 (Liu & Liu 2010)"),
    "quadric": SmoothingKernel("quadric", 2.0, 1.0, "quadric smoothing function, Liu, Liu & Lam 2003"),
}


def get_smoothing_kernel(name: str) -> SmoothingKernel:
    """Look a smoothing kernel up by name; unknown names raise SceneError listing the valid ones."""
    try:
        return SMOOTHING_KERNELS[name]
    except (KeyError, TypeError):
        raise SceneError(
            f"unknown smoothing kernel {name!r}; expected one of {', '.join(SMOOTHING_KERNELS)}"
        ) from None


def evaluate(name: str, offsets: np.ndarray, h: float, device="cpu") -> tuple[np.ndarray, np.ndarray]:
    """W and grad W of kernel ``name`` at offsets x_ij (shape (n, 3), [m]); runs the device funcs."""
    offsets = np.ascontiguousarray(offsets, dtype=np.float32).reshape(-1, 3)
    n = len(offsets)
    x = wp.array(offsets, dtype=wp.vec3, device=device)
    w = wp.zeros(n, dtype=float, device=device)
    g = wp.zeros(n, dtype=wp.vec3, device=device)
    if n:
        launch(_dev.evaluate_kernel(name), n, [x, float(h)], [w, g], device=device)
    return w.numpy(), g.numpy()


#: a fluid start's lattice: its layer spacing over d (square layers of spacing d in x and y, each shifted by
#: (d/2, d/2) from the one below for "fcc"); the lattice's volume per particle is layer d^3
LATTICE_LAYER = {"cubic": 1.0, "fcc": 1.0 / math.sqrt(2.0)}


def lattice_offsets(spacing: float, radius: float, lattice: str = "cubic") -> np.ndarray:
    """Offsets of a lattice (spacing d) within ``radius`` of the origin, origin included: "cubic" the simple cubic
    lattice; "fcc" square layers of spacing d stacked d / sqrt 2 apart, each shifted by (d/2, d/2) (face-centred
    cubic, nearest neighbours d apart; the sampler's fcc block is the same lattice turned 45 degrees about z, which
    changes no kernel sum)."""
    c = LATTICE_LAYER[lattice]
    n = int(math.ceil(radius / (c * spacing))) + 1
    k = np.arange(-n, n + 1)
    i, j, l = (a.reshape(-1) for a in np.meshgrid(k, k, k, indexing="ij"))
    s = 0.0 if lattice == "cubic" else 0.5
    g = np.stack([i + s * l, j + s * l, c * l], axis=1) * spacing
    return g[np.linalg.norm(g, axis=1) < radius]


@functools.lru_cache(maxsize=64)
def lattice_sum(name: str, h: float, spacing: float, lattice: str = "cubic") -> float:
    """sum_j W(x_ij, h) [1/m^3] for an interior particle of a perfect lattice (``lattice_offsets``), self included."""
    kernel = get_smoothing_kernel(name)
    offsets = lattice_offsets(spacing, kernel.support_radius(h), lattice)
    w, _ = evaluate(name, offsets, h)
    return float(np.sum(w.astype(np.float64)))


def calibrated_mass(name: str, h: float, spacing: float, rest_density: float, lattice: str = "cubic") -> float:
    """Particle mass m [kg] with rest_density = m sum_j W_ij on a perfect lattice (report 7.3)."""
    return rest_density / lattice_sum(name, h, spacing, lattice)


def first_layer_density(name: str, h: float, spacing: float, gap: float, rest_density: float = 1.0,
                        lattice: str = "cubic") -> float:
    """Density [kg/m^3] of a fluid particle in the first layer of a half-space lattice (spacing d,
    calibrated mass; ``lattice_offsets``' layers, the first one square) whose layer sits ``gap`` [m] above one
    Akinci wall layer (square lattice at spacing d, V_b = 1 / sum_k W_bk). Physics note section 7: at gap = d
    this reads ~6 % over rho0 (cubic lattice)."""
    kernel = get_smoothing_kernel(name)
    support = kernel.support_radius(h)
    n = int(math.ceil(support / spacing)) + 1
    a = np.arange(-n, n + 1) * spacing
    gx, gy = np.meshgrid(a, a, indexing="ij")
    plane = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    w_wall, _ = evaluate(name, plane, h)
    volume = 1.0 / float(np.sum(w_wall.astype(np.float64)))
    c, s = LATTICE_LAYER[lattice], 0.0 if lattice == "cubic" else 0.5
    layers = int(math.ceil(support / (c * spacing))) + 1
    fluid = np.concatenate([plane + [s * (k % 2) * spacing, s * (k % 2) * spacing, k * c * spacing]
                            for k in range(layers)])
    w_fluid, _ = evaluate(name, fluid, h)
    w_bound, _ = evaluate(name, plane + [0.0, 0.0, gap], h)
    mass = calibrated_mass(name, h, spacing, rest_density, lattice)
    return mass * float(np.sum(w_fluid.astype(np.float64))) + rest_density * volume * float(np.sum(w_bound.astype(np.float64)))


@functools.lru_cache(maxsize=64)
def wall_gap(name: str, h: float, spacing: float, lattice: str = "cubic") -> float:
    """Distance [m] between an Akinci wall layer and the first fluid layer at which that layer sits
    at rest density (bisection; about 1.1 d for the cubic kernel on the cubic lattice, physics note section 7;
    about 0.95 d on the fcc lattice, whose second layer is d / sqrt 2 above the first)."""
    lo, hi = 0.8 * spacing, 1.6 * spacing
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if first_layer_density(name, h, spacing, mid, 1.0, lattice) > 1.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
