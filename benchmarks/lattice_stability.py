"""Is a fluid start's lattice a stable rest state of the SPH pressure force under load? (issue #31)

    python -m benchmarks.lattice_stability                      # the table: every start, kernel and h/d below
    python -m benchmarks.lattice_stability --kernel cubic --h 1.0 1.2 --layer 0.5 0.7071 1.0

Under a uniform particle pressure P the symmetric pressure force a_i = -(2 P / rho0) V sum_j grad W(x_i - x_j)
(V = m / rho0, the calibrated volume: 1 / sum_j W_ij on the lattice itself) acts like a pair repulsion, and a
displacement wave u_j = u exp(i q . x_j) feels a = -(2 P V / rho0) D(q) u with the dynamical matrix
D(q) = sum_j (1 - cos q . x_j) H(x_j), H the Hessian of W. The pressure solve sees a wave through its density
change, d rho = i m G(q) . u with G(q) = sum_j sin(q . x_j) grad W(x_j); an (in)compressible solver adds a stiff
term along G, so the waves it cannot see are the ones with u perpendicular to G (for G = 0: all three). The
lattice is a stable rest state under P > 0 when D(q) is positive on those waves at every q; the figure reported
is the smallest stiffness k d^2 / (P / rho0) = 2 V d^2 lambda over a grid of the Brillouin zone, and the wave
it belongs to. The starts are the Bravais lattices of square layers (spacing d in x and y, d = 2 r) stacked
``layer`` d apart, each layer shifted by ``shift`` (d, d) from the one below: shift 0, layer 1 the cubic lattice;
shift 1/2 with layer 1/2 BCC, with layer 1/sqrt 2 FCC (each particle in the hollow of the four below), between
them body-centred tetragonal. Every one has square layers that match a wall's square particle layers.
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from warp_sph.core.smoothing import LATTICE_LAYER, evaluate, get_smoothing_kernel


def lattice_points(spacing: float, layer: float, shift: float, radius: float) -> np.ndarray:
    """Points of the square-layer lattice (a1 = d e_x, a2 = d e_y, a3 = (s d, s d, c d)) within ``radius`` [m] of
    the origin, the origin first; ``layer`` = c and ``shift`` = s in units of d = ``spacing`` [m]."""
    n = int(math.ceil(radius / (min(layer, 1.0) * spacing))) + 2
    k = np.arange(-n, n + 1)
    i, j, l = (a.ravel() for a in np.meshgrid(k, k, k, indexing="ij"))
    x = np.stack([(i + shift * l) * spacing, (j + shift * l) * spacing, l * layer * spacing], axis=1)
    r = np.linalg.norm(x, axis=1)
    x = x[r < radius]
    return x[np.argsort(np.linalg.norm(x, axis=1), kind="stable")]


def reciprocal(spacing: float, layer: float, shift: float) -> np.ndarray:
    """Rows b_k with a_i . b_k = 2 pi delta_ik [1/m]."""
    a = np.array([[spacing, 0.0, 0.0], [0.0, spacing, 0.0], [shift * spacing, shift * spacing, layer * spacing]])
    return 2.0 * np.pi * np.linalg.inv(a).T


def hessians(name: str, x: np.ndarray, h: float, step: float) -> np.ndarray:
    """H(x_j) [1/m^5], shape (n, 3, 3): central differences of the project's kernel gradient over +-step [m]."""
    H = np.empty((len(x), 3, 3))
    for b in range(3):
        e = np.zeros(3)
        e[b] = step
        _, gp = evaluate(name, x + e, h)
        _, gm = evaluate(name, x - e, h)
        H[:, :, b] = (gp.astype(np.float64) - gm.astype(np.float64)) / (2.0 * step)
    return 0.5 * (H + H.transpose(0, 2, 1))


class Lattice:
    """One start (kernel ``name``, smoothing length ``h`` [m], square spacing d [m], ``layer`` and ``shift`` in d)
    with its neighbours, calibrated volume V [m^3] and per-neighbour gradients and Hessians."""

    def __init__(self, name: str, h: float, spacing: float, layer: float = 1.0, shift: float = 0.0):
        self.name, self.h, self.d, self.layer, self.shift = name, h, spacing, layer, shift
        support = get_smoothing_kernel(name).support_radius(h)
        x = lattice_points(spacing, layer, shift, support + 1e-9 * spacing)
        w, _ = evaluate(name, x, h)
        self.volume = 1.0 / float(np.sum(w.astype(np.float64)))     # m / rho0 with rho0 = m sum_j W_ij
        self.x = x[1:]                                              # the neighbours, self excluded
        _, g = evaluate(name, self.x, h)
        self.grad = g.astype(np.float64)
        self.H = hessians(name, self.x, h, 1e-3 * spacing)
        self.b = reciprocal(spacing, layer, shift)

    @property
    def volume_per_particle(self) -> float:
        """The lattice's own volume per particle over d^3 [-] (1 cubic, 1/sqrt 2 FCC, 1/2 BCC)."""
        return self.layer

    def dynamical(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(q) [1/m^5] and G(q) [1/m^4] of one wave vector q [1/m]."""
        phase = self.x @ q
        D = np.einsum("j,jab->ab", 1.0 - np.cos(phase), self.H)
        G = np.sin(phase) @ self.grad
        return D, G

    def stiffness(self, q: np.ndarray) -> tuple[float, np.ndarray, float, np.ndarray]:
        """(k_all, u_all, k_hidden, u_hidden): the smallest k d^2 / (P / rho0) = 2 V d^2 lambda of D(q) over all
        polarisations and over those with no density change (u . G = 0), and their polarisations [-]."""
        D, G = self.dynamical(q)
        scale = 2.0 * self.volume * self.d ** 2
        lam, vec = np.linalg.eigh(D)
        k_all, u_all = scale * float(lam[0]), vec[:, 0]
        gn = float(np.linalg.norm(G))
        if gn <= 1e-9 * float(np.linalg.norm(self.grad, axis=1).max()) * len(self.x):
            return k_all, u_all, k_all, u_all
        g = G / gn
        basis = np.linalg.svd(np.eye(3) - np.outer(g, g))[0][:, :2]   # the plane perpendicular to G
        lam2, vec2 = np.linalg.eigh(basis.T @ D @ basis)
        return k_all, u_all, scale * float(lam2[0]), basis @ vec2[:, 0]

    def scan(self, n: int = 8) -> dict:
        """The smallest stiffnesses over an n^3 grid of the Brillouin zone (fractions f of the reciprocal vectors,
        f in (-1/2, 1/2], q = 0 left out), with their wave vectors (in units of pi / d) and polarisations."""
        f = (np.arange(n) - n // 2 + 1) / n
        best = {"all": (np.inf, None, None), "hidden": (np.inf, None, None)}
        for fi in f:
            for fj in f:
                for fk in f:
                    if fi == fj == fk == 0.0:
                        continue
                    q = np.array([fi, fj, fk]) @ self.b
                    k_all, u_all, k_hid, u_hid = self.stiffness(q)
                    for key, k, u in (("all", k_all, u_all), ("hidden", k_hid, u_hid)):
                        if k < best[key][0]:
                            best[key] = (k, q, u)
        out = {}
        for key, (k, q, u) in best.items():
            out[key] = {"k": k, "q_pi_over_d": [round(float(v) * self.d / np.pi, 3) for v in q],
                        "u": [round(float(v), 3) for v in (u if u[np.argmax(np.abs(u))] > 0 else -u)]}
        return out

    def column_slip(self) -> float:
        """k d^2 / (P / rho0) of the wave whose columns (particles stacked straight above each other) move along z
        in a checkerboard, q = (pi / d, pi / d, 0), u = e_z: the slip of the cubic lattice's columns (issue #31)."""
        D, _ = self.dynamical(np.array([np.pi / self.d, np.pi / self.d, 0.0]))
        return 2.0 * self.volume * self.d ** 2 * float(D[2, 2])
    @property
    def solver_lattice(self) -> str | None:
        """The name PBF's calibration gives this start ("cubic" or "fcc", ``fluid[].lattice``), None for a start no
        scene samples (bcc, the --layer stackings)."""
        for name, layer in LATTICE_LAYER.items():
            shift = 0.0 if name == "cubic" else 0.5
            if math.isclose(self.layer, layer) and math.isclose(self.shift, shift):
                return name
        return None

    def pbf_jacobi(self, n: int = 8) -> dict:
        """PBF's Jacobi solve on this lattice (issue #31): the constraint C_i = rho_i / rho0 - 1 linearised, a
        correction dx = J^T lambda (dx_i = sum_j V (lambda_i + lambda_j) grad W_ij) with lambda = -C / (D + eps) changes
        a wave lambda_j = cos(q . x_j) of C by the factor 1 - A(q) / (D + eps), A(q) = |sum_j V grad W_j sin(q . x_j)|^2
        the symbol of J J^T and D = sum_j |V grad W_j|^2 its diagonal (interior particle). Returns the largest
        A / D over an n^3 grid of the Brillouin zone and its wave (in pi / d); ``factor_at_default``: that wave's
        factor at PBF's default eps (``pbf.relaxation`` absent: ``pbf_lattice.auto_epsilon`` on this start's
        lattice, 3/4 of the finer-searched A_max less D0: -1/3 at A_max; None for a start no scene samples) and
        ``epsilon_default`` that eps over D0; ``relaxation_convergent`` and ``relaxation_monotone``: the smallest
        pbf.relaxation (eps over the solver's D0, ``rest_denominator``: the start's own lattice's sum, cubic or fcc,
        as the solver computes it; the cubic lattice's with this lattice's mass for a start no scene samples) at
        which no wave grows (factor >= -1) and no wave overshoots (factor >= 0); ``relaxation_smoother``: the Jacobi
        smoother's optimum for the upper half of the waves (A in [A_max / 2, A_max]: D + eps = 3/4 A_max, factors
        within +-1/3 there)."""
        from warp_sph.methods.solvers.pbf_lattice import auto_epsilon, rest_denominator

        g = self.volume * self.grad
        D = float(np.sum(g * g))
        f = (np.arange(n) - n // 2 + 1) / n
        F = np.stack(np.meshgrid(f, f, f, indexing="ij"), axis=-1).reshape(-1, 3)
        Q = F @ self.b
        A = np.sum((np.sin(Q @ self.x.T) @ g) ** 2, axis=1)
        k = int(np.argmax(A))
        lattice = self.solver_lattice
        rest = (self.name, self.h, self.d, self.volume, 1.0, lattice or "cubic")   # m = V, rho0 = 1: V = m / rho0
        D0 = rest_denominator(*rest)
        eps = auto_epsilon(*rest) if lattice else None
        return {"A_over_D": float(A[k] / D), "q_pi_over_d": [round(float(v) * self.d / np.pi, 3) for v in Q[k]],
                "D_over_D0": D / D0, "epsilon_default": None if eps is None else eps / D0,
                "factor_at_default": None if eps is None else 1.0 - float(A[k]) / (D + eps),
                "relaxation_convergent": (0.5 * float(A[k]) - D) / D0, "relaxation_monotone": (float(A[k]) - D) / D0,
                "relaxation_smoother": (0.75 * float(A[k]) - D) / D0}


STARTS = {"cubic": (1.0, 0.0), "bcc": (0.5, 0.5), "fcc": (1.0 / math.sqrt(2.0), 0.5)}


def table(kernels, hs, starts, d: float = 0.05, n: int = 8) -> list[dict]:
    """One row per (start, kernel, h/d): volume per particle over d^3, neighbours within the support, the
    calibrated V / d^3, the column slip and the scan's smallest stiffnesses."""
    rows = []
    for start in starts:
        layer, shift = STARTS[start] if isinstance(start, str) else start
        for name in kernels:
            for hd in hs:
                L = Lattice(name, hd * d, d, layer, shift)
                s = L.scan(n)
                rows.append({"start": start if isinstance(start, str) else f"layer {layer:g} shift {shift:g}",
                             "kernel": name, "h_per_d": hd, "volume_per_particle_d3": layer,
                             "neighbours": int(len(L.x)), "calibrated_volume_d3": L.volume / d ** 3,
                             "column_slip": L.column_slip() if shift == 0.0 else None,
                             "min_all": s["all"], "min_hidden": s["hidden"], "pbf_jacobi": L.pbf_jacobi(n)})
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kernel", nargs="+", default=["cubic", "quadric", "quintic"])
    ap.add_argument("--h", nargs="+", type=float, default=None, help="h / d (default: each kernel's default)")
    ap.add_argument("--start", nargs="+", default=list(STARTS), choices=list(STARTS))
    ap.add_argument("--layer", nargs="+", type=float, default=None,
                    help="instead of --start: layer spacings / d of shift-1/2 stackings (0.5 BCC .. 0.7071 FCC)")
    ap.add_argument("--grid", type=int, default=8, help="points per axis of the Brillouin-zone grid")
    a = ap.parse_args(argv)
    starts = [(c, 0.5) for c in a.layer] if a.layer else a.start
    rows = []
    for name in a.kernel:
        hs = a.h or [get_smoothing_kernel(name).default_h_per_spacing]
        rows += table([name], hs, starts, n=a.grid)
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
