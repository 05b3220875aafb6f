"""An independent best-effort Fokker-Planck solver, and the native backend's time over its time.

The competitor is written from a plain description of the problem and nothing of the package's solvers:

* graded finite volumes in the cell masses, flux ``J = -d(f Pr)/dp`` between cell centres (the Ito form, so a
  jump of ``f`` at a grid edge, as Muser's cutoff has at ``p_c``, needs nothing special); the start split between
  the two cells at ``p0``; an absorbing wall at ``p = 0`` (``Pr = 0`` there) or, where ``f ~ p^2`` keeps the mass
  away from 0, a closed bottom at ``p_bottom``; a closed top at ``p0 + top sqrt(V)``;
* cells uniform in ``s(p) = p / w + lambda ln(p / p_bottom)`` (logarithmic near the bottom, uniform above
  ``lambda w``) or, with a wall at 0, in ``p^(1/k)``, per segment between the knots (``p0``, ``p_c``, the
  native answer's first edge), so that all are edges;
* the final state as ``exp(tau_end L) m0`` by CRAM of order 16 in partial fractions (Pusa's published
  coefficients: 8 complex tridiagonal solves by the Thomas algorithm in one numba kernel);
* Richardson on nested grids (each cell halved in ``s``): ``(4 m_2N - m_N)/3`` per coarse cell and for the zero
  weight.

Two variants answer rtol 1e-6: :func:`adaptive`, with its own estimate and refinement as the package answers, and
:func:`competitor` on the smallest rung of a ladder of cell counts whose true error (known only to the
benchmark) is at most the native answer's, with no estimate (the best case for a solver of this kind).  The grid
knobs (``w``, ``p_bottom``, ``k``, ``top``) were tuned per problem by hand.

The table: per problem (mirror Gaussian, Feller, the Fig. 1 second-order scenes), the native backend at rtol 1e-6
and both variants (L1 error, cells, warm time), and the native time over theirs: medians of interleaved calls.

    python benchmarks/fp_competitor.py [--quick]
"""
from __future__ import annotations

import numpy as np
from numba import njit

from common import PAPER_PC, answer_edges, cell_masses, cli, fig1_scene, fmt, interleaved, section, table

#: the competitor's grid per Fig. 1 scene, tuned by hand on 256 cells (the best of w = 1e-4 ... 3e-2 and a bottom
#: 1e-8 ... 0.1 of the floor): (w, bottom / floor)
FIG1_GRID = {4.0: (1e-4, 0.1), 1.0: (1e-3, 0.1), 0.25: (1e-2, 1e-4), 0.01: (3e-2, 1e-8)}

# CRAM of order 16 (Pusa, Nucl. Sci. Eng. 182, 297 (2016), doi:10.13182/NSE15-26): poles theta_j and residues
# alpha_j of the upper half plane and the limit alpha_0, as published
CRAM16_THETA = np.array([
    -1.0843917078696988026e1 + 1.9277446167181652284e1j, -5.2649713434426468895e0 + 1.6220221473167927305e1j,
    5.9481522689511774808e0 + 3.5874573620183222829e0j, 3.5091036084149180974e0 + 8.4361989858843750826e0j,
    6.4161776990994341923e0 + 1.1941223933701386874e0j, 1.4193758971856659786e0 + 1.0925363484496722585e1j,
    4.9931747377179963991e0 + 5.9968817136039422260e0j, -1.4139284624888862114e0 + 1.3497725698892745389e1j])
CRAM16_ALPHA = np.array([
    -5.0901521865224915650e-7 - 2.4220017652852287970e-5j, 2.1151742182466030907e-4 + 4.3892969647380673918e-3j,
    1.1339775178483930527e2 + 1.0194721704215856450e2j, 1.5059585270023467528e1 - 5.7514052776421819979e0j,
    -6.4500878025539646595e1 - 2.2459440762652096056e2j, -1.4793007113557999718e0 + 1.7686588323782937906e0j,
    -6.2518392463207918892e1 - 1.1190391094283228480e1j, 4.1023136835410021273e-2 - 1.5743466173455468191e-1j])
CRAM16_ALPHA0 = 2.1248537104952237488e-16


@njit(cache=True, nogil=True)
def _cram16(lower, diag, upper, t, m, theta, alpha, alpha0):  # pragma: no cover - numba
    """``exp(t L) m`` for the tridiagonal ``L`` (``lower[i] = L[i+1, i]``, ``upper[i] = L[i, i+1]``)."""
    n = diag.size
    out = alpha0 * m
    cp = np.empty(n, dtype=np.complex128)
    x = np.empty(n, dtype=np.complex128)
    for j in range(theta.size):  # (t L - theta_j) x = alpha_j m, Thomas without pivoting
        th = theta[j]
        b = t * diag[0] - th
        cp[0] = t * upper[0] / b if n > 1 else 0.0
        x[0] = alpha[j] * m[0] / b
        for i in range(1, n):
            a = t * lower[i - 1]
            b = t * diag[i] - th - a * cp[i - 1]
            if i < n - 1:
                cp[i] = t * upper[i] / b
            x[i] = (alpha[j] * m[i] - a * x[i - 1]) / b
        for i in range(n - 2, -1, -1):
            x[i] -= cp[i] * x[i + 1]
        for i in range(n):
            out[i] += 2.0 * x[i].real
    return out


def _s_of_p(p, w: float, bottom: float, power: float):
    """The grid coordinate: ``p/w + power ln(p/bottom)`` (``bottom > 0``: ``power`` weighs the log part), else
    ``p**(1/power)`` (a wall at 0)."""
    return p / w + power * np.log(p / bottom) if bottom > 0.0 else p ** (1.0 / power)


def _p_of_s(s: np.ndarray, w: float, bottom: float, power: float) -> np.ndarray:
    """The inverse of :func:`_s_of_p`.  For the log map, with ``u = ln(p/(power w))``: ``u + e^u = K`` (``K =
    s/power + ln(bottom/(power w))``), solved by Newton from ``min(K, ln K)`` (convex: monotone convergence; 12 steps
    reach round-off from any start used here)."""
    if bottom <= 0.0:
        return s ** power
    k = s / power + np.log(bottom / (power * w))
    u = np.where(k > 1.0, np.log(np.maximum(k, 1.0)), k)
    for _ in range(12):
        eu = np.exp(u)
        u = u - (u + eu - k) / (1.0 + eu)
    return power * w * np.exp(u)


def edges_for(n: int, p0: float, V: float, knots: tuple, w: float, bottom: float, power: float = 1.0,
              top: float = 9.0) -> np.ndarray:
    """About ``n`` cells from ``bottom`` (0: the wall) to ``p0 + top sqrt(V)``, every knot an edge, uniform in
    :func:`_s_of_p` within each segment, segments sharing the cells by their length in ``s``."""
    top = p0 + top * np.sqrt(V)
    pts = np.array([bottom] + sorted(k for k in set(knots) if bottom < k < top) + [top])
    sp = _s_of_p(pts, w, bottom, power)
    counts = np.maximum(2, np.round(n * np.diff(sp) / (sp[-1] - sp[0])).astype(int))
    seg = np.repeat(np.arange(counts.size), counts)  # the segment of every cell's lower edge
    frac = np.concatenate([np.arange(c) / c for c in counts])
    s = sp[seg] + frac * (sp[seg + 1] - sp[seg])
    e = _p_of_s(s, w, bottom, power)
    e[np.r_[0, np.cumsum(counts)[:-1]]] = pts[:-1]  # the knots exactly
    return np.r_[e, top]


def solve_on(edges: np.ndarray, f, p0: float, tau: float, wall: bool) -> tuple[np.ndarray, float]:
    """``(cell masses, zero weight)`` at ``tau`` on one grid."""
    h = np.diff(edges)
    c = 0.5 * (edges[1:] + edges[:-1])
    fc = np.asarray(f(c), dtype=float) / h  # f Pr = (f / h) m
    dist = np.diff(c)
    lower = fc[:-1] / dist  # L[i+1, i]: flux from cell i into cell i + 1
    upper = fc[1:] / dist  # L[i, i+1]
    diag = np.zeros(c.size)
    diag[:-1] -= lower
    diag[1:] -= upper
    if wall:  # Pr = 0 at p = 0: the flux out through the wall face
        diag[0] -= fc[0] / c[0]
    m0 = np.zeros(c.size)
    j = int(np.searchsorted(edges, p0))
    m0[j - 1] = (c[j] - p0) / (c[j] - c[j - 1])
    m0[j] = (p0 - c[j - 1]) / (c[j] - c[j - 1])
    m = _cram16(lower, diag, upper, tau, m0, CRAM16_THETA, CRAM16_ALPHA, CRAM16_ALPHA0)
    return m, 1.0 - float(m.sum())


def competitor(n: int, f, p0: float, V: float, knots: tuple, w: float, bottom: float, wall: bool,
               power: float = 1.0, top: float = 9.0):
    """``(edges, masses, zero weight)``: Richardson on ``n`` and ``2n`` nested cells (the fine grid's new edges at
    the coarse cells' midpoints in ``s``)."""
    coarse = edges_for(n, p0, V, knots, w, bottom, power, top)
    return (coarse, *_richardson(solve_on(coarse, f, p0, 0.5 * V, wall),
                                 solve_on(_nested(coarse, w, bottom, power), f, p0, 0.5 * V, wall)))


def _nested(coarse: np.ndarray, w: float, bottom: float, power: float) -> np.ndarray:
    """The grid with every cell of ``coarse`` halved in ``s``."""
    fine = np.empty(2 * coarse.size - 1)
    fine[::2] = coarse
    fine[1::2] = _p_of_s(0.5 * (_s_of_p(coarse[:-1], w, bottom, power) + _s_of_p(coarse[1:], w, bottom, power)),
                         w, bottom, power)
    return fine


def _richardson(coarse: tuple, fine: tuple) -> tuple:
    """``R(N, 2N)``: the masses and zero weight ``(4 fine - coarse)/3``, the fine masses summed to the coarse cells."""
    (m1, z1), (m2, z2) = coarse, fine
    return (4.0 * (m2[::2] + m2[1::2]) - m1) / 3.0, (4.0 * z2 - z1) / 3.0


def adaptive(rtol: float, f, p0: float, V: float, knots: tuple, w: float, bottom: float, wall: bool,
             power: float = 1.0, top: float = 9.0, n_start: int = 32):
    """The competitor answering with its own error estimate, as the package does: Richardson on ``N``, ``2N`` and
    ``4N`` cells, the answer ``R(2N, 4N)`` on the ``2N`` grid, its estimate ``|R(2N, 4N) - R(N, 2N)|_1 / 7`` on the
    ``N`` cells (the fourth-order term over the second's: ``(2^4 - 1)/2``, rounded down); where it misses ``rtol``
    the next level has ``N (est / (0.5 rtol))^(1/4)`` cells, up to 8 levels.  Returns ``(edges, masses, zero
    weight, estimate, levels)``."""
    n = n_start
    for level in range(1, 9):
        e1 = edges_for(n, p0, V, knots, w, bottom, power, top)
        e2 = _nested(e1, w, bottom, power)
        e3 = _nested(e2, w, bottom, power)
        y1, y2, y3 = (solve_on(e, f, p0, 0.5 * V, wall) for e in (e1, e2, e3))
        (r12, z12), (r23, z23) = _richardson(y1, y2), _richardson(y2, y3)
        est = (float(np.sum(np.abs(r23[::2] + r23[1::2] - r12))) + abs(z23 - z12)) / 7.0
        if est <= rtol:
            break
        n = int(np.ceil(n * max(1.5, min(8.0, (est / (0.5 * rtol)) ** 0.25))))
    return e2, r23, z23, est, level


def cases() -> dict:
    """``name -> (p0, V, f, competitor settings, error of (edges, masses, zero weight))``."""
    import diffusion_pr as dp

    def exact(density, zero):
        return lambda e, m, z: float(np.sum(np.abs(m - cell_masses(density, e))) + abs(z - zero))

    out = {
        "mirror": (1.0, 1.0, lambda p: np.ones_like(p), dict(knots=(1.0,), w=np.inf, bottom=0.0, wall=True, power=2.0),
                   exact(lambda p: dp.mirror_gaussian_density(p, 1.0, 1.0), dp.persson_zero_weight(1.0, 1.0))),
        "feller": (1.0, 1.0, dp.ProportionalDiffusivity(1.0),
                   dict(knots=(1.0,), w=np.inf, bottom=0.0, wall=True, power=3.0, top=30.0),
                   exact(lambda p: dp.feller_density(p, 1.0, 0.5, 1.0), dp.feller_zero_weight(1.0, 0.5, 1.0))),
    }
    for zeta, pc in PAPER_PC.items():
        p0, V, f = fig1_scene(zeta)
        ref = dp.propagate(p0, V, diffusivity=f, backend="native", rtol=1e-10)
        floor = float(answer_edges(ref)[0])  # the question's non-contact weight: the mass below the floor

        def err(e, m, z, ref=ref, floor=floor):
            k = int(np.searchsorted(e, floor))  # an edge (a knot)
            return float(np.sum(np.abs(np.diff(ref.cdf(e[k:])) - m[k:]))
                         + abs(z + float(np.sum(m[:k])) - ref.zero_weight))

        w, depth = FIG1_GRID[zeta]
        out[f"fig1 zeta {zeta:g}"] = (p0, V, f, dict(knots=(p0, pc, floor), w=w, bottom=depth * floor, wall=False),
                                      err)
    return out


def measure(quick: bool) -> list:
    """One row per problem: native and both competitor variants at rtol 1e-6."""
    import diffusion_pr as dp

    repeats = 5 if quick else 15
    ladder = [int(round(16 * 2 ** (k / 4))) for k in range(0, 26)]  # 16 ... 1218 cells, 2^(1/4) apart
    rows = []
    for name, (p0, V, f, opts, err) in cases().items():
        def native(p0=p0, V=V, f=f):
            return dp.propagate(p0, V, diffusivity=f, backend="native", rtol=1e-6)

        r = native()
        e_nat = err(answer_edges(r), np.diff(r.cdf(answer_edges(r))), r.zero_weight)
        pick = next(((n, e) for n in ladder if (e := err(*competitor(n, f, p0, V, **opts))) <= min(1e-6, e_nat)),
                    None)
        e_a, m_a, z_a, est_a, levels = adaptive(1e-6, f, p0, V, **opts)
        calls = {"native": native, "adaptive": lambda p0=p0, V=V, f=f, opts=opts: adaptive(1e-6, f, p0, V, **opts)}
        if pick is not None:
            calls["oracle"] = lambda p0=p0, V=V, f=f, opts=opts, n=pick[0]: competitor(n, f, p0, V, **opts)
        t = interleaved(calls, repeats)
        rows.append(dict(problem=name, native_error=e_nat, native_estimate=r.error_estimate,
                         native_ms=1e3 * t["native"],
                         adaptive_error=err(e_a, m_a, z_a), adaptive_cells=int(e_a.size - 1), adaptive_levels=levels,
                         adaptive_ms=1e3 * t["adaptive"], oracle_n=pick[0] if pick else None,
                         oracle_error=pick[1] if pick else None,
                         oracle_ms=1e3 * t["oracle"] if pick else None))
    return rows


def run(quick: bool = False) -> str:
    rows = measure(quick)
    body = table(["problem", "native: L1 error", "estimate", "time [ms]", "competitor (own estimate): error",
                  "cells (levels)", "time [ms]", "native / it", "competitor (oracle-picked N): N", "error",
                  "time [ms]", "native / it"],
                 [(r["problem"], fmt(r["native_error"], ".1e"), fmt(r["native_estimate"], ".1e"),
                   fmt(r["native_ms"], ".2f"), fmt(r["adaptive_error"], ".1e"),
                   f"{r['adaptive_cells']} ({r['adaptive_levels']})", fmt(r["adaptive_ms"], ".2f"),
                   fmt(r["native_ms"] / r["adaptive_ms"], ".2f"), r["oracle_n"] or "-", fmt(r["oracle_error"], ".1e"),
                   fmt(r["oracle_ms"], ".2f"),
                   fmt(r["native_ms"] / r["oracle_ms"] if r["oracle_ms"] else None, ".2f")) for r in rows])
    return section("Native Fokker-Planck against the independent competitor (rtol 1e-6)", body,
                   "L1 errors against the closed forms (mirror, Feller) or the native rtol-1e-10 answer (Fig. 1 "
                   "second-order scenes, Muser's cutoff at the paper's p_c; the mass below the native floor counts "
                   "as non-contact). Medians of interleaved warm calls in one process. The oracle-picked competitor "
                   "is the smallest rung of its ladder whose error is at most the native answer's and at most 1e-6.")


if __name__ == "__main__":
    cli(run, __doc__)
