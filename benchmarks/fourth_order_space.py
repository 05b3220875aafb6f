"""What a fourth-order spatial scheme would buy the balanced closures: cells against error (issue 10).

The thirty-sixth session wrote that issue 10's closure row needs "a spatial scheme of higher order" besides a
higher-order shell rule; the fiftieth session measured the shell rule (``shell_rule_balance.py``: no gain against
the midpoint rule with Richardson) and the deep layer (``closure_floor_bound.py``: not enough alone). This script
measures the spatial half in a small numpy solver of its own, so that only the spatial scheme differs:

* **second order**: the engine's finite volumes (``operator.bands``: diffusive flux ``-(g_{i+1} m_{i+1} -
  g_i m_i)/d`` with ``g = f/h`` at the centres, the central drift of the balanced stages), the mean as
  ``sum c_i m_i``; Richardson ``R(N, 2N) = (4 X(2N) - X(N))/3`` (fourth order), as the engine does;
* **fourth order, explicit**: the same cell masses, the flux at each face ``J = -(f M')' + a M'`` from the
  primitive ``M`` (known exactly at the edges: cumulative sums of the masses), its derivatives from the five
  nearest edges (Fornberg's weights: pentadiagonal, one-sided at the ends), ``f'`` in closed form; the mean as
  ``p_max M(p_max) - int M dp`` with ``M`` interpolated cubically; Richardson ``(16 X(2N) - X(N))/15`` (sixth
  order);
* **fourth order, compact** (:class:`Compact`): the equation of ``M`` itself, ``M_tau = f M_pp + (f_p - a) M_p``,
  by the high-order compact scheme for convection-diffusion, ``P dM/dtau = Q M`` with ``P`` and ``Q`` both
  tridiagonal, so that CRAM's shifted solves ``(t Q - theta P)`` stay tridiagonal as the engine's are; the same
  mean and Richardson as the explicit one.

Both take the closure's 48 uniform midpoint shells (one balance multiplier per shell, mean ``p0`` at its end, found
by secant), CRAM-16 exponentials by sparse LU per pole, on nested grids (:func:`grid`: logarithmic in the deep
layer, linear above, ``p0`` an edge) from ``1e-8 p*`` to 0.45, both ends closed (a reflecting bottom: a problem
of its own, the same for both schemes). The start is the state after the first ``--skip`` shells of the finest grid's
second-order solve (a delta at ``p0`` split between its two cells), given to every grid as exact cell sums; the
reference is the second-order Richardson ``R`` of the two finest grids from there (checked against the
fourth-order one). Errors: L1 of the masses on each grid. Writes ``results/fourth_order_space.md``.

With ``--skip 0`` the comparison starts from the delta at ``p0`` itself (the engine's start: every grid's two
cells at ``p0`` half each); the compact scheme's start is then ``corrected_delta_start`` (``--start-shift 1/24``, the
default) or the sampled step (``--start-shift 0``: fourth order lost, the fifty-first session's finding; 1/16
and 1/12 lose it too). Results files get ``_delta`` (``_delta_sampled``, ``_delta_shift<value>``) in their names.

With ``--absorbing`` the bottom, at ``--floor`` ``p*`` (default ``1e-16``, the closures' own floor), absorbs as
the engine's wall does, for ``zeta <= 0.01``, where most of the probability crosses the deep layer to it; writes
``results/fourth_order_space_absorbing.md``.

    python benchmarks/fourth_order_space.py [--zetas 0.1 0.25] [--closures local_g1_balanced]
    python benchmarks/fourth_order_space.py --absorbing --zetas 0.1 0.01
    python benchmarks/fourth_order_space.py --skip 0 [--start-shift 0] [--absorbing]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diffusion_pr.closures as C  # noqa: E402
from bench_fokker_planck import SPECTRUM  # noqa: E402
from diffusion_pr.solvers.fv.compact import corrected_delta_start, hoc_bands  # noqa: E402
from diffusion_pr.solvers.fv.cram import pfd_coefficients  # noqa: E402
from diffusion_pr.solvers.fv.operator import centres  # noqa: E402
from shell_rule_balance import Scene, multiplier  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "fourth_order_space.md"
E_STAR, P0, SHELLS = 8.0 / 3.0, 0.004, 48
THETA, RES, R_INF, _ = pfd_coefficients(16)


def fornberg(x0: float, xs: np.ndarray, m: int) -> np.ndarray:
    """Weights of the derivatives 0..m at ``x0`` from values at ``xs`` (Fornberg, Math. Comp. 51, 699 (1988),
    doi:10.1090/S0025-5718-1988-0935077-0): ``w[k] @ values`` is the k-th derivative."""
    n = xs.size
    w = np.zeros((m + 1, n))
    w[0, 0] = 1.0
    c1 = 1.0
    c4 = xs[0] - x0
    for i in range(1, n):
        mn = min(i, m)
        c2 = 1.0
        c5, c4 = c4, xs[i] - x0
        for j in range(i):
            c3 = xs[i] - xs[j]
            c2 *= c3
            if j == i - 1:
                for k in range(mn, 0, -1):
                    w[k, i] = c1 * (k * w[k - 1, i - 1] - c5 * w[k, i - 1]) / c2
                w[0, i] = -c1 * c5 * w[0, i - 1] / c2
            for k in range(mn, 0, -1):
                w[k, j] = (c4 * w[k, j] - k * w[k - 1, j]) / c3
            w[0, j] = c4 * w[0, j] / c3
        c1 = c2
    return w


def grid(scene: Scene, n0: int, level: int) -> np.ndarray:
    """Edges of the nested family: uniform in ``xi(p) = p / w + lam ln(p / p_bottom)`` (logarithmic in the deep
    layer below ``lam w``, linear above; ``w = p0 / 4``, ``lam`` giving the two parts about equal shares), ``n0``
    cells halved ``level`` times, ``p0`` an edge with the same spacing on both sides (a jump of the spacing would
    add an odd power of ``h`` to the error expansion)."""
    p_bottom, w, lam, xi = mapping(scene)
    lo, hi, x0 = float(xi(p_bottom)), float(xi(0.45)), float(xi(P0))
    dx = (hi - lo) / n0
    n_lo = max(2, round((x0 - lo) / dx))
    k = 2 ** level
    e = p_of_xi(scene, x0 + dx / k * np.arange(-n_lo * k, (n0 - n_lo) * k + 1))
    e[n_lo * k] = P0
    return e


def mapping(scene: Scene) -> tuple:
    """``(p_bottom, w, lam, xi)`` of :func:`grid`'s coordinate ``xi(p) = p / w + lam ln(p / p_bottom)``."""
    p_bottom, p_max, w = getattr(scene, "floor_factor", 1e-8) * scene.kz * scene.q_min, 0.45, 0.25 * P0
    lam = (p_max / w) / math.log(p_max / p_bottom)
    return p_bottom, w, lam, lambda p: p / w + lam * np.log(p / p_bottom)


def p_of_xi(scene: Scene, targets: np.ndarray) -> np.ndarray:
    """The pressures at the coordinates ``targets`` (Newton on ``ln p``)."""
    p_bottom, w, lam, xi = mapping(scene)
    y = np.minimum(np.log(p_bottom) + targets / lam, np.log(np.maximum(w * targets, p_bottom)))  # below the root
    for _ in range(100):  # xi(e^y) is increasing and convex in y, so Newton climbs to the root
        step = (xi(np.exp(y)) - targets) / (np.exp(y) / w + lam)
        y -= step
        if np.max(np.abs(step)) < 1e-15:
            break
    return np.exp(y)


def diffusivity_and_slope(p: np.ndarray, kq: float) -> tuple:
    """``(f, df/dp)`` of the shell's diffusivity ``f = g^2``, ``g = p / (p + kz q)`` (``kq = kz q`` [pressure]), in
    closed form: a difference quotient's round-off (1e-10 of ``f'``) is amplified 1e6x where the compact scheme
    differences its coefficients twice (it then converged at second order only)."""
    g = p / (p + kq)
    return g * g, 2.0 * g * kq / (p + kq) ** 2


def primitive_quadrature(edges: np.ndarray) -> np.ndarray:
    """Weights ``omega`` of ``int M dp ~ sum_j omega_j M_j`` over the edges, ``M`` cubic through the 4 nearest edges
    on every interval (fourth order), each interval's Lagrange integrals taken in its local coordinate (in
    absolute ``p`` the monomials cancel catastrophically on fine grids)."""
    n = edges.size - 1
    omega = np.zeros(n + 1)
    for k in range(n):
        j0 = min(max(k - 1, 0), n - 3)
        h = edges[k + 1] - edges[k]
        ts = (edges[j0:j0 + 4] - edges[k]) / h  # the interval is [0, 1]
        for j in range(4):
            others = np.delete(ts, j)
            integ = np.polyint(np.poly(others) / np.prod(ts[j] - others))
            omega[j0 + j] += h * (np.polyval(integ, 1.0) - np.polyval(integ, 0.0))
    return omega


class Scheme:
    """One spatial scheme on one grid: its operators per shell model and its mean functional."""

    def __init__(self, scene: Scene, edges: np.ndarray, order: int) -> None:
        self.scene, self.edges, self.order = scene, edges, order
        self.c = centres(edges)
        n = self.c.size
        if order == 2:
            self.mean_weights = self.c.copy()
        else:
            omega = primitive_quadrature(edges)
            # M_j = sum_{i<j} m_i: mean = sum_i m_i (p_max - sum_{j>i} omega_j)
            tail = np.cumsum(omega[::-1])[::-1]  # tail[j] = sum_{j' >= j} omega_j'
            self.mean_weights = edges[-1] - tail[1:]
            self.stencils = []
            for k in range(1, n):  # interior faces
                j0 = min(max(k - 2, 0), n - 4)
                self.stencils.append((j0, fornberg(edges[k], edges[j0:j0 + 5], 2)))
        self.cache: dict = {}

    def operators(self, q: float) -> tuple:
        """Sparse ``(L_fb, L_w)`` of the shell model at ``q`` on the masses: ``L = L_fb - A L_w``."""
        if q in self.cache:
            return self.cache[q]
        sc = self.scene
        qp = sc.q_min if sc.closure == "local_g1_balanced" else q
        f_m = C.LocalResponseDiffusivity(q, sc.kz)
        b_m = C.LoadExcessDrift(q, qp, sc.kz)
        w_m = C.RigidApproachBalance(qp, sc.kz)
        e = self.edges
        n = self.c.size
        faces = e[1:-1]
        if self.order == 2:
            h = np.diff(e)
            g = f_m(self.c) / h
            k_int = 1.0 / np.diff(self.c)
            ops = []
            for diffusion, a in ((True, b_m(faces)), (False, w_m(faces))):
                rows, cols, vals = [], [], []
                i = np.arange(n - 1)
                # flux J at face i+1/2 (upwards) as coefficients on m_i and m_{i+1}
                ji = (k_int * g[:-1] if diffusion else 0.0) + a * 0.5 / h[:-1]
                jr = (-k_int * g[1:] if diffusion else 0.0) + a * 0.5 / h[1:]
                for col, coef in ((i, ji), (i + 1, jr)):
                    rows += [i, i + 1]
                    cols += [col, col]
                    vals += [-coef, coef]
                ops.append(sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                         shape=(n, n)))
            self.cache[q] = (ops[0], ops[1])
            return self.cache[q]
        # fourth order: J_k = -f M'' - f' M' + a M' at face k from M at the stencil's edges
        f_f, fp_f = diffusivity_and_slope(faces, sc.kz * q)
        ops = []
        for diffusion, a in ((True, b_m(faces)), (False, w_m(faces))):
            rows, cols, vals = [], [], []
            for idx, (j0, w) in enumerate(self.stencils):
                k = idx + 1
                coef_m = (-f_f[idx] * w[2] - fp_f[idx] * w[1] if diffusion else 0.0) + a[idx] * w[1]  # on M_j0..j0+4
                # M_j = sum_{i<j} m_i: the flux's coefficient on m_i is the sum of coef_m over j > i
                on_m = np.cumsum(coef_m[::-1])[::-1]  # on_m[t] = sum_{t' >= t} coef_m[t'] -> M_{j0+t'} includes m_i
                for t in range(1, 5):  # M_{j0+t} - M_{j0} = m_{j0} .. m_{j0+t-1}: coefficient of m_{j0+t-1}
                    i = j0 + t - 1
                    cf = on_m[t]
                    # J_k leaves cell k-1 and enters cell k
                    rows += [k - 1, k]
                    cols += [i, i]
                    vals += [-cf, cf]
            ops.append(sp.csc_matrix((np.array(vals), (np.array(rows), np.array(cols))), shape=(n, n)))
        self.cache[q] = (ops[0], ops[1])
        return self.cache[q]

    def mean(self, m: np.ndarray) -> float:
        return float(self.mean_weights @ m)


class Compact:
    """A fourth-order compact scheme on the primitive ``M`` at the edges (tridiagonal on both sides).

    ``M(p, tau)``, the probability below ``p``, obeys ``M_tau = f M_pp + (f_p - a) M_p`` (``a = b - A w``), with
    ``M`` fixed at both closed ends. In the grid's coordinate ``xi`` (uniform spacing ``h``) that is
    ``M_tau = A M'' + B M'`` with ``A = f / p_xi^2`` and ``B = (f_p - a) / p_xi - f p_xixi / p_xi^3``. The scheme is
    the high-order compact one for time-dependent convection-diffusion (Spotz and Carey, Numer. Methods Partial
    Differ. Equ. 17, 657 (2001); the derivation below; :func:`compact_order_check` confirms its order on a test with
    known derivatives): the central differences' ``h^2`` terms (``A u_4 + 2 B u_3``, ``u_k`` the k-th derivative),
    written through the equation itself, give ``P M_tau = Q M`` with

        P = 1 + h^2/12 (d2 + beta d1),   Q = (A + h^2 kappa/12) d2 + (B + h^2 gamma/12) d1,
        beta = (B - 2 A_1)/A,  gamma = B_2 + beta B_1,  kappa = 2 B_1 + A_2 + beta (A_1 + B),

    (``A_k``, ``B_k`` the coefficients' k-th derivatives in ``xi``, central differences with a step of 1e-3 in ``xi``
    of the coefficients in closed form), both tridiagonal, so that every shifted solve of the exponential,
    ``(t Q - theta P)``, stays tridiagonal.
    """

    def __init__(self, scene: Scene, edges: np.ndarray) -> None:
        self.scene, self.edges = scene, edges
        self.x = mapping(scene)[3](edges)
        self.h = float(np.mean(np.diff(self.x[1:-1])))
        # on M: mean = p_max M_n - int M dp (the explicit scheme's quadrature)
        self.mean_weights = -primitive_quadrature(edges)
        self.mean_weights[-1] += edges[-1]
        self.cache: dict = {}

    def _at(self, x: np.ndarray, q: float) -> tuple:
        """``(A, B_fb, B_w)`` at the coordinates ``x``: ``B = B_fb + A_bal B_w``."""
        sc = self.scene
        p_bottom, w, lam, _ = mapping(sc)
        p = p_of_xi(sc, x)
        p_xi = 1.0 / (1.0 / w + lam / p)
        p_xixi = p_xi ** 3 * lam / p ** 2
        qp = sc.q_min if sc.closure == "local_g1_balanced" else q
        f, f_p = diffusivity_and_slope(p, sc.kz * q)
        b, w_bal = C.LoadExcessDrift(q, qp, sc.kz)(p), C.RigidApproachBalance(qp, sc.kz)(p)
        return f / p_xi ** 2, (f_p - b) / p_xi - f * p_xixi / p_xi ** 3, w_bal / p_xi

    def parts(self, q: float) -> list:
        """``[(A, A_1, A_2), (B_fb, ...), (B_w, ...)]`` at the interior edges."""
        if q not in self.cache:
            x = self.x[1:-1]
            s = 1e-3
            vals = [self._at(x + d, q) for d in (-s, 0.0, s)]
            self.cache[q] = [(vals[1][j], (vals[2][j] - vals[0][j]) / (2 * s),
                              (vals[2][j] - 2 * vals[1][j] + vals[0][j]) / s ** 2) for j in range(3)]
        return self.cache[q]

    def pencil(self, q: float, a_bal: float) -> tuple:
        """Sparse ``(P, Q)`` on ``M_0 .. M_n`` (the end rows: ``M_tau = 0``)."""
        (A, A1, A2), (Bf, Bf1, Bf2), (Bw, Bw1, Bw2) = self.parts(q)
        return hoc_pencil(self.h, (A, A1, A2), (Bf + a_bal * Bw, Bf1 + a_bal * Bw1, Bf2 + a_bal * Bw2))

    def mean(self, M: np.ndarray) -> float:
        # the weights sum to p_bottom (the quadrature is exact for constants), so this is p_max M_n - p_bottom M_0 -
        # int M dp; M_0 = z taken out first, since most of M is z where the zero weight is large (0.92 at
        # zeta = 0.001), which the sum would otherwise cancel at round-off
        return float(self.mean_weights @ (M - M[0]))


def hoc_pencil(h: float, a: tuple, b: tuple) -> tuple:
    """Sparse ``(P, Q)`` of the compact scheme for ``u_tau = A u'' + B u'`` on a uniform grid of spacing ``h``
    (:class:`Compact`; the bands are the package's :func:`diffusion_pr.solvers.fv.compact.hoc_bands`): ``a = (A,
    A', A'')`` and ``b = (B, B', B'')`` at the interior nodes; the two end rows are ``u_tau = 0``."""
    (pl, pd, pu), (ql, qd, qu) = hoc_bands(h, a, b)
    return sp.diags([pl, pd, pu], [-1, 0, 1], format="csc"), sp.diags([ql, qd, qu], [-1, 0, 1], format="csc")


def compact_order_check() -> list:
    """:func:`hoc_pencil`'s error on a test with known derivatives: ``A = 1 + sin(x)/2``, ``B = 3 cos(2x)``,
    ``u = sin(3x)`` on ``[0, 2]``, ``max |P^-1 Q u - (A u'' + B u')|`` on 20, 40, 80, 160 intervals (the end rows
    given their exact values): falls 16x per doubling where the derivation is right."""
    out = []
    for n in (20, 40, 80, 160):
        x = np.linspace(0.0, 2.0, n + 1)
        xi = x[1:-1]
        P, Q = hoc_pencil(x[1] - x[0], (1 + 0.5 * np.sin(xi), 0.5 * np.cos(xi), -0.5 * np.sin(xi)),
                          (3 * np.cos(2 * xi), -6 * np.sin(2 * xi), -12 * np.cos(2 * xi)))
        exact = (1 + 0.5 * np.sin(x)) * (-9 * np.sin(3 * x)) + 3 * np.cos(2 * x) * 3 * np.cos(3 * x)
        rhs = Q @ np.sin(3 * x)
        rhs[0], rhs[-1] = exact[0], exact[-1]
        out.append((n, float(np.max(np.abs(splu(P).solve(rhs) - exact)))))
    return out


def expm_pencil(P, Q, t: float, y: np.ndarray) -> np.ndarray:
    """``exp(t P^-1 Q) y`` by CRAM-16: ``r_inf y + 2 Re sum_j c_j (t Q - theta_j P)^-1 P y``."""
    py = (P @ y).astype(complex)
    out = R_INF * y
    for theta, c in zip(THETA, RES):
        out = out + 2.0 * np.real(c * splu((t * Q - theta * P).astype(complex).tocsc()).solve(py))
    return out


def run_compact(scheme: Compact, shells: list, y: np.ndarray, start_shift: float | None = None) -> np.ndarray:
    """``[z, m]`` after ``shells`` by the compact scheme, from ``[z, m]`` (``M_0 = z`` moves only where the bottom
    absorbs, :class:`CompactAbsorbing`); with ``start_shift``, ``y`` is the split delta at ``p0`` and ``M`` starts
    as the package's ``corrected_delta_start`` with that shift (1/24: fourth order kept; 0: the sampled step)."""
    M = np.concatenate(([y[0]], y[0] + np.cumsum(y[1:])))
    if start_shift is not None:
        j = int(np.searchsorted(scheme.edges, P0))
        if scheme.edges[j] != P0 or not np.array_equal(M, corrected_delta_start(M.size, j, 0.0)):
            raise ValueError("run_compact: start_shift needs the split delta at p0, p0 an edge")
        M = corrected_delta_start(M.size, j, start_shift)
    a_guess = 0.0
    for dv, q_mid, _, _ in shells:
        h = 0.5 * dv
        a_guess = multiplier(lambda a: scheme.mean(expm_pencil(*scheme.pencil(q_mid, a), h, M)) - P0, a_guess)
        M = expm_pencil(*scheme.pencil(q_mid, a_guess), h, M)
    return np.concatenate(([M[0]], np.diff(M)))


def expm(L, t: float, y: np.ndarray) -> np.ndarray:
    """CRAM-16 in partial fractions: ``r_inf y + 2 Re sum_j c_j (t L - theta_j)^-1 y``."""
    tl = (t * L).astype(complex)
    eye = sp.identity(L.shape[0], dtype=complex, format="csc")
    out = R_INF * y
    for theta, c in zip(THETA, RES):
        out = out + 2.0 * np.real(c * splu((tl - theta * eye).tocsc()).solve(y.astype(complex)))
    return out


def run(scheme: Scheme, shells: list, y: np.ndarray) -> np.ndarray:
    a_guess = 0.0
    for dv, q_mid, _, _ in shells:
        l_fb, l_w = scheme.operators(q_mid)
        h = 0.5 * dv

        a_guess = multiplier(lambda a: scheme.mean(expm(l_fb - a * l_w, h, y)) - P0, a_guess)
        y = expm(l_fb - a_guess * l_w, h, y)
    return y


def aggregate(m_fine: np.ndarray, factor: int) -> np.ndarray:
    return m_fine.reshape(-1, factor).sum(axis=1)


# --- an absorbing bottom (the engine's wall far below the floor), for zeta <= 0.01 -------------------------------


class SchemeAbsorbing(Scheme):
    """:class:`Scheme` (second order) on ``[z, m]``: the bottom edge absorbs (``Pr = 0`` there: the diffusive
    outflow ``f_0 u_0 / (c_0 - p_bottom)`` into ``z``, as the engine's wall face), ``z`` counted at ``p = 0``."""

    def __init__(self, scene: Scene, edges: np.ndarray) -> None:
        super().__init__(scene, edges, 2)
        self.mean_weights = np.concatenate(([0.0], self.c))

    def operators(self, q: float) -> tuple:
        key = ("abs", q)
        if key not in self.cache:
            l_fb, l_w = super().operators(q)
            n = self.c.size
            big = [sp.bmat([[sp.csc_matrix((1, 1)), None], [None, op]], format="lil") for op in (l_fb, l_w)]
            out = C.LocalResponseDiffusivity(q, self.scene.kz)(self.c[:1])[0] / (self.edges[1] - self.edges[0]) \
                / (self.c[0] - self.edges[0])
            big[0][1, 1] -= out
            big[0][0, 1] += out
            self.cache[key] = tuple(b.tocsc() for b in big)
            assert self.cache[key][0].shape == (n + 1, n + 1)
        return self.cache[key]


class CompactAbsorbing(Compact):
    """:class:`Compact` with an absorbing bottom: ``M_0 = z`` moves by ``M_tau = f M_pp`` there (``Pr = 0``:
    ``M_xi = 0``), ``M_xixi`` from ``M_0 .. M_3`` to third order given ``M_xi = 0``."""

    def __init__(self, scene: Scene, edges: np.ndarray) -> None:
        super().__init__(scene, edges)
        k = np.arange(1.0, 4.0)
        rows = np.array([k ** 2 / 2, k ** 3 / 6, k ** 4 / 24])  # M_k - M_0 = h^2 (rows . (M2, h M3, h^2 M4))
        self.one_sided = np.linalg.solve(rows, np.array([1.0, 0.0, 0.0]))  # M2 ~ sum_k c_k (M_k - M_0) / h^2

    def pencil(self, q: float, a_bal: float) -> tuple:
        P, Q = super().pencil(q, a_bal)
        a0 = self._at(self.x[:1], q)[0][0]
        Q = Q.tolil()
        c = self.one_sided * a0 / self.h ** 2
        Q[0, 0] = -c.sum()
        for j in range(3):
            Q[0, j + 1] = c[j]
        return P, Q.tocsc()


def aggregate_zm(y: np.ndarray, factor: int) -> np.ndarray:
    return np.concatenate((y[:1], aggregate(y[1:], factor)))


def absorbing(zeta: float, closure: str, n0: int, levels: int, skip: int, floor: float,
              start_shift: float | None = None) -> list:
    """Rows of the second-order and compact schemes with the absorbing bottom at ``floor p*``."""
    scene = Scene(zeta, closure, 8)
    scene.floor_factor = floor
    shells = scene.shells(SHELLS)
    top = levels + 1
    e_ref = grid(scene, n0, top)
    n_ref = e_ref.size - 1
    y = np.zeros(n_ref + 1)
    j = int(np.searchsorted(e_ref, P0))
    y[j] = y[j + 1] = 0.5  # the cells on both sides of p0 ([z, m]: m_i is y[i + 1])
    ref_scheme = SchemeAbsorbing(scene, e_ref)
    start = run(ref_scheme, shells[:skip], y)
    rest = shells[skip:]
    fine = run(ref_scheme, rest, start)
    half = run(SchemeAbsorbing(scene, grid(scene, n0, top - 1)), rest, aggregate_zm(start, 2))
    ref = (4 * aggregate_zm(fine, 2) - half) / 3
    rows, x, prev = [], {}, {}
    for level in range(levels):
        e = grid(scene, n0, level)
        y0 = aggregate_zm(start, 2 ** (top - level))
        r_here = aggregate_zm(ref, 2 ** (top - 1 - level))
        cells = []
        for kind in ("2", "compact"):
            try:
                x[kind, level] = (run(SchemeAbsorbing(scene, e), rest, y0) if kind == "2" else
                                  run_compact(CompactAbsorbing(scene, e), rest, y0, start_shift))
            except RuntimeError:
                cells.append("balance failed")
                prev.pop(kind, None)
                continue
            err = float(np.sum(np.abs(x[kind, level] - r_here)))
            cells.append(f"{err:.2e}" + (f" ({math.log2(prev[kind] / err):.1f})" if kind in prev else ""))
            prev[kind] = err
        for kind, div in (("2", 3.0), ("compact", 15.0)):
            if level >= 1 and (kind, level - 1) in x and (kind, level) in x:
                rr = ((div + 1) * aggregate_zm(x[kind, level], 2) - x[kind, level - 1]) / div
                cells.append(f"{float(np.sum(np.abs(rr - aggregate_zm(ref, 2 ** (top - level))))):.2e}")
            else:
                cells.append("")
        rows.append(f"| `{closure}` | {zeta:g} | {e.size - 1} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    rows.append(f"| | | reference: {n_ref} cells, zero weight {ref[0]:.4f} | | | | |")
    return rows


def main_absorbing(args) -> None:
    """``--absorbing``: the second-order and compact schemes with the absorbing bottom at ``--floor p*``."""
    lines = ["# The compact scheme with an absorbing bottom "
             "(`python benchmarks/fourth_order_space.py --absorbing`)", "",
             f"As the main table, but the bottom at {args.floor:g} p* absorbs (the engine's wall: Pr = 0 there; "
             "the second-order scheme's outflow f_0 u_0/(c_0 - p_bottom), the compact scheme's M_tau = f M_pp with "
             "M_p = 0 from a third-order one-sided difference), the zero weight z counted at p = 0 and in the L1 "
             "errors; the explicit fourth-order scheme left out. The reference: the second-order Richardson of the "
             "two finest grids." + _start_text(args), "",
             "| closure | zeta | N | 2nd order X(N) | compact X(N) | R2(N/2, N) | compact R4(N/2, N) |",
             "|---|---|---|---|---|---|---|"]
    for closure in args.closures:
        for zeta in args.zetas:
            t0 = time.perf_counter()
            lines += absorbing(zeta, closure, args.n0, args.levels, args.skip, args.floor, _start_shift(args))
            lines[-1] = lines[-1][:-2] + f" ({time.perf_counter() - t0:.0f} s) |"
    out = _out(OUT.with_name("fourth_order_space_absorbing.md"), args, [0.1, 0.01])
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


def _start_shift(args) -> float | None:
    return args.start_shift if args.skip == 0 else None


def _start_text(args) -> str:
    if args.skip != 0:
        return ""
    return (" From the delta at p0 (the split delta of every grid's two cells at p0); the compact scheme's start "
            f"`corrected_delta_start` with the shift {args.start_shift:.6g}" +
            (" (1/24: corrected)." if args.start_shift == 1 / 24 else " (not 1/24: uncorrected)."))


def _out(base: Path, args, default_zetas: list) -> Path:
    """The results file: ``base``, with the zetas where they are not the default, and ``_delta`` (or
    ``_delta_sampled``) where the comparison starts from the delta."""
    tail = "" if args.zetas == default_zetas else "_" + "_".join(f"{z:g}" for z in args.zetas)
    if args.skip == 0:
        tail += "_delta" + ("" if args.start_shift == 1 / 24 else "_sampled" if args.start_shift == 0 else
                            f"_shift{args.start_shift:.4g}")
    return base.with_name(base.stem + tail + ".md")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.1, 0.25])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    ap.add_argument("--n0", type=int, default=40, help="cells of the coarsest grid")
    ap.add_argument("--levels", type=int, default=5, help="grids N0 .. N0 2^(levels-1) compared")
    ap.add_argument("--skip", type=int, default=4, help="shells before the comparison starts")
    ap.add_argument("--start-shift", type=float, default=1 / 24,
                    help="with --skip 0: the compact start's shift of M next to p0 (1/24 corrected, 0 sampled)")
    ap.add_argument("--absorbing", action="store_true", help="the bottom absorbs (main_absorbing)")
    ap.add_argument("--floor", type=float, default=1e-16, help="with --absorbing: the bottom in units of p*")
    args = ap.parse_args(argv)
    if args.absorbing:
        main_absorbing(args)
        return
    lines = ["# A fourth-order spatial scheme for the balanced closures (`python benchmarks/fourth_order_space.py`)",
             "", f"Fig. 1 scene, {SHELLS} uniform midpoint shells, the comparison from the state after {args.skip} "
             "shells (exact cell sums of the finest grid's), CRAM-16. L1 error of the masses against the reference "
             "(second-order Richardson of the two finest grids, 2 and 4 levels above the finest compared); in "
             "brackets log2 of the fall per doubling. `R2`: (4 X(2N) - X(N))/3 of the second-order scheme (the "
             "engine's answer, cells 2N); `R4`: (16 X(2N) - X(N))/15 of a fourth-order one (explicit: five bands; "
             "compact: P dM/dtau = Q M, both tridiagonal)." + _start_text(args), "",
             "| closure | zeta | N | 2nd order X(N) | 4th order X(N) | compact X(N) | R2(N/2, N) | R4(N/2, N) | "
             "compact R4(N/2, N) |",
             "|---|---|---|---|---|---|---|---|---|"]
    check = compact_order_check()
    lines[3:3] = ["", "The compact pencil on a test with known derivatives (`compact_order_check`), max error on "
                  "20/40/80/160 intervals: " + ", ".join(f"{e:.2e}" for _, e in check) + " (ratios " +
                  ", ".join(f"{a / b:.1f}" for (_, a), (_, b) in zip(check, check[1:])) + ")."]
    print(lines[4], flush=True)
    shells_all = None
    for closure in args.closures:
        for zeta in args.zetas:
            t0 = time.perf_counter()
            scene = Scene(zeta, closure, 8)  # (its own grid unused: the shells and the models)
            shells_all = scene.shells(SHELLS)
            top = args.levels + 1  # reference grids: levels top-1 and top
            e_ref = grid(scene, args.n0, top)
            n_ref = e_ref.size - 1
            ref_scheme = Scheme(scene, e_ref, 2)
            y = np.zeros(n_ref)
            j = int(np.searchsorted(e_ref, P0))  # e_ref[j] == p0 exactly (grid)
            y[j - 1] = y[j] = 0.5
            start = run(ref_scheme, shells_all[:args.skip], y)
            rest = shells_all[args.skip:]
            fine = run(ref_scheme, rest, start)
            half = run(Scheme(scene, grid(scene, args.n0, top - 1), 2), rest, aggregate(start, 2))
            ref = (4 * fine.reshape(-1, 2).sum(axis=1) - half) / 3  # on the level top-1 grid
            prev: dict = {}
            x = {}
            for level in range(args.levels):
                factor = 2 ** (top - 1 - level)
                e = grid(scene, args.n0, level)
                y0 = aggregate(start, 2 ** (top - level))
                r_here = aggregate(ref, factor)
                cells = []
                for order in (2, 4, "compact"):
                    try:
                        x[order, level] = (run_compact(Compact(scene, e), rest, np.concatenate(([0.0], y0)),
                                                       _start_shift(args))[1:]
                                           if order == "compact" else
                                           run(Scheme(scene, e, order), rest, y0))
                    except RuntimeError:  # the fourth-order operator on too few cells (not an M-matrix)
                        cells.append("balance failed")
                        prev.pop(order, None)
                        continue
                    err = float(np.sum(np.abs(x[order, level] - r_here)))
                    tag = f" ({math.log2(prev[order] / err):.1f})" if order in prev else ""
                    prev[order] = err
                    cells.append(f"{err:.2e}{tag}")
                for order, div in ((2, 3.0), (4, 15.0), ("compact", 15.0)):
                    if level >= 1 and (order, level - 1) in x and (order, level) in x:
                        coarse = x[order, level - 1]
                        fine_agg = x[order, level].reshape(-1, 2).sum(axis=1)
                        rr = ((div + 1) * fine_agg - coarse) / div
                        err = float(np.sum(np.abs(rr - aggregate(ref, factor * 2))))
                        tag = f" ({math.log2(prev[order, 'R'] / err):.1f})" if (order, "R") in prev else ""
                        prev[order, "R"] = err
                        cells.append(f"{err:.2e}{tag}")
                    else:
                        cells.append("")
                lines.append(f"| `{closure}` | {zeta:g} | {e.size - 1} | " + " | ".join(cells) + " |")
                print(lines[-1], flush=True)
            smallest = [float(np.min(x["compact", lv])) for lv in range(args.levels) if ("compact", lv) in x]
            check4 = ((16 * x[4, args.levels - 1].reshape(-1, 2).sum(axis=1) - x[4, args.levels - 2]) / 15)
            move = float(np.sum(np.abs(check4 - aggregate(ref, 2 ** (top - args.levels + 1)))))  # (both finest ran)
            lines.append(f"| | | reference: {n_ref} cells; R4 of the two finest compared grids differs from it by "
                         f"{move:.1e}; the compact scheme's smallest mass per grid (coarsest first): "
                         f"{', '.join(f'{v:.1e}' for v in smallest)} | | | | | | "
                         f"({time.perf_counter() - t0:.0f} s) |")
            print(lines[-1], flush=True)
    out = _out(OUT, args, [0.1, 0.25])
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

