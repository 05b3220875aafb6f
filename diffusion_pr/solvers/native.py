"""Native backend: conservative, positivity-preserving implicit finite volumes.

Solves (SPEC section 4, in the diffusion time ``tau``; Müser, PRL 100, 055504
(2008), doi:10.1103/PhysRevLett.100.055504)::

    dP/dtau = - d/dp [ a(p, tau) P ] + d^2/dp^2 [ f(p, tau) P ],   P(tau=0) = delta(p - p0)

on ``[0, p_max]`` (``p_max`` from :meth:`FokkerPlanckProblem.upper_bound`).

Space
    Cell averages ``P_i`` on a non-uniform grid (:func:`._common.domain_edges`),
    Ito flux form: between cells ``i`` and ``i+1`` (centres ``x_i``)::

        F_{i+1/2} = -(f_{i+1} P_{i+1} - f_i P_i) / (x_{i+1} - x_i) + a_{i+1/2} P_face,

    so ``f P`` is what is continuous and ``P`` may jump where ``f`` jumps (the
    seed cutoff at ``p_c``, placed on an edge).  ``P_face`` is the central
    average where that keeps the off-diagonals non-negative
    (``-2 f_i/dx <= a <= 2 f_{i+1}/dx``, second order) and the upwind value
    elsewhere (first order; only where the cell Péclet number exceeds 2).
    ``p = 0`` absorbs with the ghost value ``f P = 0``: the outflow is
    ``-dQ/dp`` at 0 (``Q = f P``), closed linearly (``Q_0/x_0``, exact for the
    mirror Gaussian whose ``Q'' = 0`` at the wall; used for non-absorbing
    ``f``) or by the parabola through ``(0, 0), (x_0, Q_0), (x_1, Q_1)``
    (second order; used when ``f`` is absorbing, e.g. Feller's ``f ∝ p``),
    plus the upwind outflow of a drift towards the wall.  The outflow is added
    to ``zero_weight`` with the stage weights of the time stepper, so total
    probability is conserved to round-off.  No flux at ``p_max``.  Without
    drift and with the linear closure the scheme conserves ``sum h_i x_i P_i``
    exactly (up to ``f P`` at ``p_max``); the quadratic closure conserves it
    to ``O(h^2)``.

Time
    TR-BDF2 (Bank et al., IEEE Trans. CAD 4, 436 (1985); Hosea & Shampine,
    Appl. Numer. Math. 20, 21 (1996)), L-stable and second order,
    ``gamma = 2 - sqrt(2)``; both stages use the matrix
    ``I - (gamma/2) dt L``.  Steps (:func:`time_grid`) are geometric in
    ``tau + TAU_C tau_end`` from the short-time start ``tau0``
    (:func:`._common.short_time_start`): small first steps on the narrow early
    peak, nearly uniform later (measured: more uniform steps are more accurate
    here because the start already has exact mass, mean and variance); they
    are rounded to powers of ``2^(1/2)`` so runs of equal steps share one
    factorization.  With a drift the nodes also follow the accumulated drift
    displacement (:func:`drift_time_grid`).  Tridiagonal solves: numba Thomas
    kernels (``cache=True``, no fastmath); ``I - c L`` is a column-diagonally
    dominant M-matrix, so no pivoting is needed.

Positivity
    Each implicit stage matrix is an M-matrix, but the explicit half of the
    trapezoidal stage and the BDF2 combination are not positivity preserving
    for large steps, so tiny negative values can appear (none were seen in the
    tests; ``diagnostics["min_density_during_run"]``).  At the end negative
    cells are set to 0 and the positive cells rescaled by the same mass, so
    total probability stays exact; the moved mass is reported in
    ``diagnostics["clipped_mass"]`` and added to ``error_estimate``.

Accuracy control
    Every grid is solved as nested levels: ``N`` fine cells with ``K``
    steps, the middle grid ``edges[::2]`` with ``K/2`` and, when needed, the
    coarse grid ``edges[::4]`` with ``K/4`` (breakpoints on edges whose index
    is a multiple of 4).  The time grids are nested too: the coarse level's
    steps (:func:`time_grid`) are split into 2 and 4 equal steps
    (:func:`_nested_steps`), so space and time errors both refine by exactly 4
    per level.  Summing the fine solution onto the middle cells, the
    Richardson estimate of the fine solution's L1 error (second order: divide
    the difference by ``2^2 - 1 = 3``) is::

        pair estimate = (sum_cells |M_fine - M_mid| + |z_fine - z_mid|) / 3
                        + clipped mass + 2 * tail mass beyond p_max.

    Measured against the closed forms it is within 5 % of the true error.  If
    it meets ``rtol`` the fine solution is returned (``returned_solution =
    "fine"``; always the case for ``n_cells`` given).  Otherwise the coarse
    level is solved and the Richardson-extrapolated masses on the middle
    cells, ``E_hi = M_fine + (M_fine - M_mid)/3`` (zero weight likewise), are
    compared with the same extrapolation one level down,
    ``E_lo = M_mid + (M_mid - M_coarse)/3``::

        extrapolated estimate = sum_cells |E_hi - E_lo| + |z_hi - z_lo|  (on the coarse cells)
                                + clipped mass + 2 * tail mass,

    i.e. the difference itself, not divided by ``2^q - 1``: it bounds the
    error of ``E_hi`` whenever the extrapolated solution converges at least
    linearly (measured: 1.5-14 times the true error on the mirror, Feller,
    seed-cutoff and smoothstep problems, against references on 8x
    subdivided grids).  The extrapolated solution is returned on the middle
    grid when this estimate is smaller than the pair's and its midpoint mean
    ``sum h x P`` is within ``rtol * p0`` of ``p0`` (exact cell averages on a
    graded grid have an ``O(h^2)`` midpoint-mean defect, which the
    extrapolation reproduces; the fine solution conserves it exactly).  It
    conserves mass exactly (both levels do); negative extrapolated values
    (round-off in the far tails) are clipped as below.
    For non-absorbing ``f`` (the smooth cutoffs, ``f ~ p^k`` with ``k >= 2``
    at the wall) no mass reaches ``p = 0`` but it creeps towards it; the
    grid resolves this logarithmically down to :func:`._common.wall_floor`
    (``1e-12`` times the cutoff scale, or where the creeping peak ends), and
    the probability below the floor (an edge of the coarse level,
    ``diagnostics["floor_edge"]``) is lumped into ``zero_weight`` in every
    level (``diagnostics["floor_mass"]``).  When a grid fails, the next one
    is :func:`._common.domain_edges` with more cells, the growth predicted
    from the pair (``error ∝ N^-2``), the extrapolation (``N^-3``) and the
    mean defect (``N^-2``), at least 1.5x; steps scale with cells
    (``STEPS_PER_CELL``).  The first grid has ``sqrt(4/rtol)`` fine cells
    (at least ``MIN_CELLS``), which meets ``rtol`` with the pair for the
    mirror Gaussian and Feller problems.  When ``max_cells`` or
    ``max_refinements`` stops the loop first, ``success=False`` and the
    message gives the estimate, cells and steps; the best solution found is
    returned.  ``diagnostics["extrapolated_cell_mass"]`` holds the pair's
    extrapolated masses on the middle grid of the returned level.
"""
from __future__ import annotations

import time
from typing import Optional, Tuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ..problem import FokkerPlanckProblem
from ..result import PressureDistribution
from ._common import cell_centres, domain_edges, is_absorbing, short_time_start, tail_mass_for, wall_floor

Array = NDArray[np.float64]

GAMMA = 2.0 - np.sqrt(2.0)
#: steps per cell of the coarse grid of a pair (tuned on the mirror Gaussian / Feller)
STEPS_PER_CELL = 0.125
#: steps grow geometrically in tau + TAU_C * tau_end
TAU_C = 0.5
#: the first pair uses this fraction of the cells expected to meet rtol (a pilot for the adaptation)
PILOT_FRACTION = 1.0
#: fewest fine cells of the first pair (a cheap floor: the pilot must see the features)
MIN_CELLS = 800
#: adapted grids aim at this fraction of rtol
TARGET_FRACTION = 0.5

_JIT: dict = {"compile_time": None}


# ----------------------------------------------------------------------------- kernels
@njit(cache=True)
def _factor(lower, diag, upper, c, cp, binv):  # pragma: no cover - numba
    """LU (Thomas) factors of ``I - c L``: ``cp`` super-diagonal ratios, ``binv`` pivots^-1."""
    n = diag.size
    binv[0] = 1.0 / (1.0 - c * diag[0])
    cp[0] = -c * upper[0] * binv[0]
    for i in range(1, n):
        binv[i] = 1.0 / (1.0 - c * diag[i] + c * lower[i] * cp[i - 1])
        cp[i] = -c * upper[i] * binv[i]


@njit(cache=True)
def _back(cp, out):  # pragma: no cover - numba
    for i in range(out.size - 2, -1, -1):
        out[i] -= cp[i] * out[i + 1]


@njit(cache=True)
def _stage_tr(ln, dn, un, ls, c, cp, binv, p, pstar):  # pragma: no cover - numba
    """Trapezoidal stage: ``(I - c L_s) pstar = (I + c L_n) p`` with ``I - c L_s`` factored."""
    n = p.size
    prev = 0.0
    for i in range(n):
        v = p[i] + c * dn[i] * p[i]
        if i > 0:
            v += c * ln[i] * p[i - 1]
        if i < n - 1:
            v += c * un[i] * p[i + 1]
        prev = (v + c * ls[i] * prev) * binv[i]
        pstar[i] = prev
    _back(cp, pstar)


@njit(cache=True)
def _stage_bdf2(l1, c, cp, binv, c1, c2, pstar, p):  # pragma: no cover - numba
    """BDF2 stage: ``(I - c L_1) p_new = c1 pstar + c2 p``, in place in ``p``."""
    prev = 0.0
    for i in range(p.size):
        prev = (c1 * pstar[i] + c2 * p[i] + c * l1[i] * prev) * binv[i]
        p[i] = prev
    _back(cp, p)


@njit(cache=True)
def _trbdf2_step(ln, dn, un, wn, vn, ls, ds, us, ws, vs, l1, d1, u1, w1, v1, p, z, dt, gamma,
                 pstar, cp, binv):  # pragma: no cover - numba
    """One TR-BDF2 step of ``dP/dtau = L(tau) P`` in place; returns the new zero weight.

    ``(ln, dn, un)``, ``(ls, ds, us)``, ``(l1, d1, u1)``: bands of ``L`` at
    ``tau_n``, ``tau_n + gamma dt``, ``tau_n + dt``; ``w*``, ``v*`` the wall
    outflow coefficients (outflow = ``w P[0] + v P[1]``).  Both stages solve with
    ``I - (gamma/2) dt L`` (for ``gamma = 2 - sqrt 2``,
    ``gamma/2 = (1 - gamma)/(2 - gamma)``).  The zero weight is advanced
    with the same stage weights, so ``sum h P + z`` is invariant.
    """
    c = 0.5 * gamma * dt
    c1 = 1.0 / (gamma * (2.0 - gamma))
    c2 = -(1.0 - gamma) ** 2 / (gamma * (2.0 - gamma))
    _factor(ls, ds, us, c, cp, binv)
    _stage_tr(ln, dn, un, ls, c, cp, binv, p, pstar)
    zs = z + c * (wn * p[0] + vn * p[1] + ws * pstar[0] + vs * pstar[1])
    _factor(l1, d1, u1, c, cp, binv)
    _stage_bdf2(l1, c, cp, binv, c1, c2, pstar, p)
    return c1 * zs + c2 * z + c * (w1 * p[0] + v1 * p[1])


@njit(cache=True)
def _run_autonomous(lower, diag, upper, wall, wall1, p, z, dts, gamma):  # pragma: no cover - numba
    """All TR-BDF2 steps ``dts`` with a constant operator; returns (z, min P seen).

    The factorization of ``I - (gamma/2) dt L`` is reused while ``dt`` stays
    the same (see :func:`time_grid`: steps come in runs of equal size).
    """
    n = p.size
    pstar = np.empty(n)
    cp = np.empty(n)
    binv = np.empty(n)
    c1 = 1.0 / (gamma * (2.0 - gamma))
    c2 = -(1.0 - gamma) ** 2 / (gamma * (2.0 - gamma))
    pmin = 0.0
    c_last = -1.0
    for k in range(dts.size):
        c = 0.5 * gamma * dts[k]
        if c != c_last:
            _factor(lower, diag, upper, c, cp, binv)
            c_last = c
        z_old = z
        _stage_tr(lower, diag, upper, lower, c, cp, binv, p, pstar)
        zs = z_old + c * (wall * (p[0] + pstar[0]) + wall1 * (p[1] + pstar[1]))
        _stage_bdf2(lower, c, cp, binv, c1, c2, pstar, p)
        z = c1 * zs + c2 * z_old + c * (wall * p[0] + wall1 * p[1])
        for i in range(n):
            if p[i] < pmin:
                pmin = p[i]
    return z, pmin


def _compile() -> float:
    """Compile (or load from cache) the kernels once; returns the seconds it took."""
    if _JIT["compile_time"] is None:
        t = time.perf_counter()
        n = 8
        lo = np.zeros(n)
        up = np.zeros(n)
        dg = -np.ones(n)
        p = np.ones(n)
        _run_autonomous(lo, dg, up, 0.0, 0.0, p, 0.0, np.array([0.1]), GAMMA)
        ps, cp, bi = np.empty(n), np.empty(n), np.empty(n)
        _trbdf2_step(lo, dg, up, 0.0, 0.0, lo, dg, up, 0.0, 0.0, lo, dg, up, 0.0, 0.0, p, 0.0, 0.1, GAMMA,
                     ps, cp, bi)
        _JIT["compile_time"] = time.perf_counter() - t
    return float(_JIT["compile_time"])


# ----------------------------------------------------------------------------- operator
def operator_bands(problem: FokkerPlanckProblem, edges: Array, tau: float = 0.0, *,
                   wall: str = "linear") -> Tuple[Array, Array, Array, float]:
    """Tridiagonal finite-volume operator ``L`` with ``dP/dtau = L P``.

    Parameters
    ----------
    problem : FokkerPlanckProblem
        Gives ``f(p, tau)`` (at cell centres) and ``a(p, tau)`` (at edges).
    edges : ndarray
        Cell edges (units of pressure), ``edges[0] = 0``.
    tau : float
        Diffusion time at which ``f`` and ``a`` are evaluated.
    wall : {"linear", "quadratic"}
        Closure of the diffusive outflow ``dQ/dp`` at ``p = 0`` (``Q = f P``,
        ghost ``Q(0) = 0``).  ``"linear"``: ``Q_0 / x_0`` (first order where
        ``Q'' != 0`` at the wall, exact for the mirror Gaussian, for which
        ``Q''(0) = 0``; keeps every column sum <= 0).  ``"quadratic"``: the
        parabola through ``(0, 0)``, ``(x_0, Q_0)``, ``(x_1, Q_1)``,
        second order (used for absorbing ``f``, e.g. Feller's ``f ∝ p``); the
        coefficient of ``Q_1`` enters the off-diagonal with the M-matrix sign.
        The zero weight follows either closure exactly.

    Returns
    -------
    lower, diag, upper : ndarray
        Bands (``lower[0]``, ``upper[-1]`` unused, 0); units 1/pressure^2.
        Off-diagonals are >= 0 and column sums are 0 except in column 0,
        whose sum is ``-wall / h_0``.
    wall0, wall1 : float
        Outflow coefficients at ``p = 0``: probability leaves into the
        ``delta(p)`` peak at the rate ``wall0 P_0 + wall1 P_1`` (``wall1 <= 0``,
        nonzero only for the quadratic closure).
    """
    edges = np.asarray(edges, dtype=float)
    h = np.diff(edges)
    x = cell_centres(edges)
    n = h.size
    f = problem.f(x, tau)
    dx = np.diff(x)
    fl, fr = f[:-1] / dx, f[1:] / dx  # diffusive coefficients at interior faces
    c_l = fl.copy()  # F_{i+1/2} = c_l P_i + c_r P_{i+1}
    c_r = -fr
    a0 = 0.0
    if problem.drift is not None:
        a_face = problem.a(edges, tau)
        a_in = a_face[1:-1]
        central = (a_in >= -2.0 * fl) & (a_in <= 2.0 * fr)
        w_l = np.where(central, 0.5, np.where(a_in > 0.0, 1.0, 0.0))
        w_r = 1.0 - w_l
        c_l = c_l + a_in * w_l
        c_r = c_r + a_in * w_r
        a0 = min(float(a_face[0]), 0.0)
    lower = np.zeros(n)
    upper = np.zeros(n)
    diag = np.zeros(n)
    lower[1:] = c_l / h[1:]
    upper[:-1] = -c_r / h[:-1]
    diag[1:] += c_r / h[1:]
    diag[:-1] -= c_l / h[:-1]
    if wall == "quadratic":
        # Q'(0) ~ Q_0 x_1/(x_0 (x_1 - x_0)) - Q_1 x_0/(x_1 (x_1 - x_0))
        c0 = f[0] * x[1] / (x[0] * (x[1] - x[0]))
        c1 = f[1] * x[0] / (x[1] * (x[1] - x[0]))
    elif wall == "linear":
        c0, c1 = f[0] / x[0], 0.0
    else:
        raise ValueError(f"wall must be 'linear' or 'quadratic'; got wall={wall!r}")
    c_wall = -c0 + a0  # F_{1/2} = c_wall P_0 + c1 P_1 at p = 0 (outflow when < 0)
    diag[0] += c_wall / h[0]
    upper[0] += c1 / h[0]
    return lower, diag, upper, float(-c_wall), float(-c1)


def time_grid(tau0: float, tau_end: float, n_steps: int, tau_c: Optional[float] = None,
              levels_per_octave: int = 2) -> Array:
    """Step sizes from ``tau0`` to ``tau_end``, geometric in ``tau + tau_c tau_end``.

    The ideal step is ``dt = (r - 1)(tau + tau_c tau_end)`` with ``r`` such
    that ``n_steps`` ideal steps reach ``tau_end``: early steps follow the
    narrow early peak (``dt ~ tau``), late ones are nearly uniform.  Each step
    is rounded down to a power of ``2^(1/levels_per_octave)`` so that steps
    come in runs of equal size and the tridiagonal factorization is reused
    (autonomous problems); this adds up to ~20 % more steps.  The last step
    lands exactly on ``tau_end``.  Units: pressure squared.
    """
    shift = (TAU_C if tau_c is None else tau_c) * tau_end
    r = ((tau_end + shift) / (tau0 + shift)) ** (1.0 / max(int(n_steps), 1))
    q = float(levels_per_octave)
    out = []
    tau = tau0
    while tau < tau_end:
        ideal = (r - 1.0) * (tau + shift)
        dt = 2.0 ** (np.floor(q * np.log2(ideal)) / q)
        if tau + dt >= tau_end * (1.0 - 1e-12) or tau_end - (tau + dt) < 0.25 * dt:
            dt = tau_end - tau
        out.append(dt)
        tau += dt
    return np.asarray(out)


def drift_time_grid(problem: FokkerPlanckProblem, tau0: float, n_steps: int, p_max: float) -> Array:
    """Step sizes for a problem with drift: half following :func:`time_grid`, half the drift.

    The nodes are equidistributed in ``mu(tau) = (k(tau)/K + S(tau)/S_end)/2``
    where ``k(tau)/K`` is the fraction of the :func:`time_grid` steps done and
    ``S(tau) = integral max_p |a| dtau`` the drift displacement so far (a drift
    mapped from magnification, ``A/D(eta)``, can be huge at small ``tau``).
    Units: pressure squared.
    """
    base = np.concatenate(([tau0], tau0 + np.cumsum(time_grid(tau0, problem.tau_end, n_steps))))
    mu1 = np.linspace(0.0, 1.0, base.size)
    probe = np.linspace(0.0, p_max, 129)[1:]
    table = np.unique(np.concatenate((base, tau0 + (problem.tau_end - tau0) * np.geomspace(1e-12, 1.0, 257))))
    amax = np.array([float(np.max(np.abs(problem.a(probe, float(t))))) for t in table])
    s_cum = np.concatenate(([0.0], np.cumsum(0.5 * (amax[1:] + amax[:-1]) * np.diff(table))))
    mu = np.interp(table, base, mu1)
    if s_cum[-1] > 0.0:
        mu = 0.5 * mu + 0.5 * s_cum / s_cum[-1]
    nodes = np.interp(np.linspace(0.0, 1.0, int(n_steps) + 1), mu, table)
    nodes[0], nodes[-1] = tau0, problem.tau_end
    dts = np.diff(nodes)
    return dts[dts > 0.0]


# ----------------------------------------------------------------------------- one solve
def _solve_on_grid(problem: FokkerPlanckProblem, edges: Array, n_steps: int, wall: str = "linear",
                   dts: Optional[Array] = None, start: Optional[tuple] = None) -> dict:
    """Integrate on one grid with about ``n_steps`` TR-BDF2 steps (or the given ``dts``); no refinement.

    ``start``: ``short_time_start(problem, edges)`` if already computed.
    """
    tau0, p, z = short_time_start(problem, edges) if start is None else start
    p = p.copy()
    if dts is not None:
        dts = np.asarray(dts, dtype=float)
    elif problem.drift is None:
        dts = time_grid(tau0, problem.tau_end, n_steps)
    else:
        dts = drift_time_grid(problem, tau0, n_steps, float(edges[-1]))
    if problem.autonomous:
        lo, dg, up, w0, w1 = operator_bands(problem, edges, 0.0, wall=wall)
        z, pmin = _run_autonomous(lo, dg, up, w0, w1, p, float(z), dts, GAMMA)
    else:
        n = p.size
        ps, cp, bi = np.empty(n), np.empty(n), np.empty(n)
        tau = tau0
        pmin = 0.0
        ops_n = operator_bands(problem, edges, tau, wall=wall)
        for dt in dts:
            ops_s = operator_bands(problem, edges, tau + GAMMA * dt, wall=wall)
            ops_1 = operator_bands(problem, edges, tau + dt, wall=wall)
            z = _trbdf2_step(*ops_n, *ops_s, *ops_1, p, float(z), float(dt), GAMMA, ps, cp, bi)
            pmin = min(pmin, float(p.min()))
            tau += dt
            ops_n = ops_1
    return {"density": p, "zero_weight": float(z), "tau0": tau0, "min_density": float(pmin),
            "n_steps": int(dts.size)}


def _make_nonnegative(density: Array, h: Array) -> Tuple[Array, float]:
    """Remove negative values without changing total mass; returns (density, moved mass)."""
    neg = density < 0.0
    if not np.any(neg):
        return density, 0.0
    m = density * h
    moved = float(-np.sum(m[neg]))
    pos_mass = float(np.sum(m[~neg]))
    out = np.where(neg, 0.0, density * (1.0 - moved / pos_mass))
    return out, moved


def _coarse_masses(density: Array, h: Array) -> Array:
    """Masses of the coarse cells of a nested pair (fine cells 2j, 2j+1)."""
    m = density * h
    return m[0::2] + m[1::2]


def _initial_cells(rtol: float) -> int:
    """Fine-grid cells of the first nested pair for a requested ``rtol``.

    Measured on the mirror Gaussian and Feller problems (``p0/sqrt(V)`` from
    0.3 to 3): the L1 error is about ``C / N^2`` with ``C`` from 1 to 4, so
    ``N = sqrt(4 / rtol)`` (2000 cells for ``1e-6``) usually meets ``rtol``
    with the first pair.  Rounded to a multiple of 4 (three nested levels).
    """
    n = int(np.ceil(PILOT_FRACTION * np.sqrt(4.0 / rtol) / 4.0) * 4)
    return int(np.clip(n, MIN_CELLS, 2 ** 16))


def _nested_steps(problem: FokkerPlanckProblem, starts: list, k_coarse: int, p_max: float) -> list:
    """Step sequences of the three nested levels (fine, middle, coarse).

    The coarse level (``starts[2]``, its own ``tau0``) gets the usual
    :func:`time_grid` (or :func:`drift_time_grid`) with ``k_coarse`` steps;
    the middle and fine levels split every coarse step into 2 and 4 equal
    steps, so the three time grids are nested and the time error refines by
    exactly 4 per level like the space error (Richardson needs both).  A
    finer level starts earlier (its ``tau0`` follows its cell width at
    ``p0``); the gap up to the coarse ``tau0`` is covered by steps doubling
    from ``tau0`` (about ``dt = tau``; the start's own error is
    ``O((tau0/tau_end)^2)``, i.e. fourth order in the cell width).
    """
    tau0_c = float(starts[2][0])
    if problem.drift is None:
        coarse = time_grid(tau0_c, problem.tau_end, k_coarse)
    else:
        coarse = drift_time_grid(problem, tau0_c, k_coarse, p_max)
    out = []
    for split, start in zip((4, 2, 1), starts):
        tau0 = float(start[0])
        pre = np.zeros(0)
        if 0.0 < tau0 < tau0_c * (1.0 - 1e-12):
            m = int(np.ceil(np.log2(tau0_c / tau0)))
            pre = np.diff(np.geomspace(tau0, tau0_c, m + 1))
        elif tau0 > tau0_c * (1.0 + 1e-12):  # cannot happen with nested grids; stay safe
            out.append(None)
            continue
        out.append(np.concatenate((pre, np.repeat(coarse / split, split))))
    return out


def _lump_below(sol: dict, h: Array, n_lump: int) -> None:
    """Move the probability of the first ``n_lump`` cells into the zero weight (the wall floor)."""
    if n_lump > 0:
        sol["floor_mass"] = float(np.sum(sol["density"][:n_lump] * h[:n_lump]))
        sol["zero_weight"] += sol["floor_mass"]
        sol["density"][:n_lump] = 0.0


def solve(
    problem: FokkerPlanckProblem,
    *,
    rtol: float = 1e-6,
    n_cells: Optional[int] = None,
    n_steps: Optional[int] = None,
    uniform: bool = False,
    max_cells: int = 2 ** 17,
    max_refinements: int = 6,
) -> PressureDistribution:
    """Solve a :class:`FokkerPlanckProblem` to L1 accuracy ``rtol``.

    Parameters
    ----------
    problem : FokkerPlanckProblem
        The problem (``tau`` from 0 to ``V/2``).
    rtol : float
        Target for the estimated L1 error of ``Pr`` (density integral plus
        zero weight), dimensionless.
    n_cells : int, optional
        Cells of the returned (fine) grid.  With ``n_cells`` given there is
        no refinement loop: one nested pair ``(n_cells/2, n_cells)`` is solved,
        the fine solution returned, and ``success`` says whether its estimate
        met ``rtol``.
    n_steps : int, optional
        Time steps of the fine solve (default ``STEPS_PER_CELL * n_cells``).
    uniform : bool
        Equal cells instead of the stretched grid.
    max_cells : int
        Cap on fine-grid cells in the refinement loop.
    max_refinements : int
        Cap on the number of grids tried.

    Returns
    -------
    PressureDistribution
        The fine solution of the pair or the Richardson-extrapolated one (see
        the module docstring); ``error_estimate`` as described there;
        ``wall_time`` excludes JIT compilation (``diagnostics["jit_compile_time"]``).
    """
    if not isinstance(problem, FokkerPlanckProblem):
        raise ValueError(f"problem must be a FokkerPlanckProblem; got {type(problem).__name__}")
    rtol = float(rtol)
    if not np.isfinite(rtol) or rtol <= 0.0:
        raise ValueError(f"rtol must be a finite number > 0; got rtol={rtol!r}")
    compile_time = _compile()
    t_start = time.perf_counter()
    tail = tail_mass_for(rtol)
    p_max = problem.upper_bound(tail_mass=tail)
    absorbing = is_absorbing(problem)
    wall_closure = "quadratic" if absorbing else "linear"
    floor = 0.0 if absorbing else wall_floor(problem)
    fixed = n_cells is not None
    align = 2 if fixed else 4
    if fixed:
        n_fine = int(n_cells) + int(n_cells) % 2
    else:
        n_fine = min(_initial_cells(rtol), int(max_cells))
        n_fine -= n_fine % 4
    n_fine = max(n_fine, 8 * align // 2)
    history = []
    best = None
    for _level in range(1 if fixed else max_refinements):
        edges = domain_edges(problem, n_fine, rtol=rtol, uniform=uniform, p_max=p_max, align=align)
        n_fine = edges.size - 1
        t_level = time.perf_counter()
        levels = [edges, edges[::2]] if fixed else [edges, edges[::2], edges[::4]]
        hs = [np.diff(e) for e in levels]
        if fixed:
            k_fine = int(n_steps) if n_steps is not None else max(8, int(round(STEPS_PER_CELL * n_fine)))
            k_fine += k_fine % 2
            sols = [_solve_on_grid(problem, edges, k_fine, wall_closure),
                    _solve_on_grid(problem, edges[::2], k_fine // 2, wall_closure)]
        else:
            k_fine = int(n_steps) if n_steps is not None else max(8, int(round(STEPS_PER_CELL * n_fine)))
            starts = [short_time_start(problem, e) for e in levels]
            steps = _nested_steps(problem, starts, max(2, k_fine // 4), p_max)
            sols = [_solve_on_grid(problem, e, k_fine, wall_closure, dts=d, start=st)
                    for e, d, st in zip(levels[:2], steps[:2], starts[:2])]
        # lump the creeping peak below the floor (an edge of the coarsest level) into the zero weight
        k_lump = 0
        if floor > 0.0:
            k_lump = max(int(np.searchsorted(levels[-1], floor, side="right")) - 1, 0)
            for j, (sol, hh) in enumerate(zip(sols, hs)):
                _lump_below(sol, hh, k_lump * (2 ** (len(levels) - 1 - j)))
        floor_edge = float(levels[-1][k_lump])
        fine, mid = sols[0], sols[1]
        mf = _coarse_masses(fine["density"], hs[0])
        mc = mid["density"] * hs[1]
        zf, zc = fine["zero_weight"], mid["zero_weight"]
        diff = float(np.sum(np.abs(mf - mc)) + abs(zf - zc))
        density, clipped = _make_nonnegative(fine["density"], hs[0])
        estimate = diff / 3.0 + clipped + 2.0 * tail
        entry = {"cells": n_fine, "steps": fine["n_steps"], "estimate": estimate, "difference": diff}
        cand = {"kind": "fine", "floor_edge": floor_edge, "edges": edges, "density": density, "zero_weight": zf, "estimate": estimate,
                "clipped": clipped, "fine": fine, "coarse": mid, "mf": mf, "mc": mc}
        ok = estimate <= rtol
        if not fixed and not ok:
            # third level: Richardson-extrapolate the pair and estimate the extrapolated error
            coarse = _solve_on_grid(problem, levels[2], k_fine // 4, wall_closure, dts=steps[2], start=starts[2])
            _lump_below(coarse, hs[2], k_lump)
            mcc = coarse["density"] * hs[2]
            zcc = coarse["zero_weight"]
            ext_hi = mf + (mf - mc) / 3.0
            z_hi = zf + (zf - zc) / 3.0
            ext_lo = _coarse_masses(mid["density"], hs[1]) + (_coarse_masses(mid["density"], hs[1]) - mcc) / 3.0
            z_lo = zc + (zc - zcc) / 3.0
            d_ext = float(np.sum(np.abs(_coarse_masses(ext_hi, np.ones_like(ext_hi)) - ext_lo)) + abs(z_hi - z_lo))
            dens_ext, clipped_ext = _make_nonnegative(ext_hi / hs[1], hs[1])
            if z_hi < 0.0:  # round-off (or a non-asymptotic level): keep the peak non-negative, mass exact
                cont = float(np.sum(dens_ext * hs[1]))
                dens_ext = dens_ext * ((cont + z_hi) / cont)
                clipped_ext += -z_hi
                z_hi = 0.0
            est_ext = d_ext + clipped_ext + 2.0 * tail
            x2 = cell_centres(levels[1])
            mean_defect = abs(float(np.sum(x2 * dens_ext * hs[1])) - problem.mean_pressure) / problem.mean_pressure
            entry.update({"extrapolated_estimate": est_ext, "extrapolated_mean_defect": mean_defect})
            mean_ok = problem.drift is not None or mean_defect <= rtol
            if est_ext < estimate and mean_ok:
                cand = {"kind": "extrapolated", "floor_edge": floor_edge, "edges": levels[1], "density": dens_ext, "zero_weight": z_hi,
                        "estimate": est_ext, "clipped": clipped_ext, "fine": fine, "coarse": mid,
                        "mf": mf, "mc": mc}
                ok = est_ext <= rtol
        entry["returned"] = cand["kind"]
        entry["seconds"] = time.perf_counter() - t_level
        history.append(entry)
        if best is None or cand["estimate"] < best["estimate"] or ok:
            best = cand
        if ok or fixed or n_fine >= max_cells:
            break
        # next grid: the smaller of the pair's (order 2) and the extrapolation's (order 3) prediction
        target = max(TARGET_FRACTION * rtol - 2.0 * tail, 0.1 * rtol)
        grow = np.sqrt(max(estimate, 1e-300) / target)
        if "extrapolated_estimate" in entry:
            # the extrapolated solution must also bring the midpoint mean to rtol (an O(h^2) defect)
            g_ext = (max(entry["extrapolated_estimate"], 1e-300) / target) ** (1.0 / 3.0)
            if problem.drift is None:
                g_ext = max(g_ext, np.sqrt(entry["extrapolated_mean_defect"] / (0.8 * rtol)))
            grow = min(grow, g_ext)
        grow = float(np.clip(grow, 1.5, 8.0))
        n_new = int(min(np.ceil(grow * n_fine / 4.0) * 4, max_cells - max_cells % 4))
        if n_new <= n_fine:
            break
        n_fine = n_new
    edges, density, estimate, clipped = best["edges"], best["density"], best["estimate"], best["clipped"]
    fine, coarse, mf, mc = best["fine"], best["coarse"], best["mf"], best["mc"]
    zero_weight = float(best["zero_weight"])
    h = np.diff(edges)
    x = cell_centres(edges)
    wall = time.perf_counter() - t_start
    ok = estimate <= rtol
    mass = float(np.sum(h * density) + zero_weight)
    mean = float(np.sum(h * x * density))
    how = "Richardson-extrapolated 3-level" if best["kind"] == "extrapolated" else "fine"
    status = (f"{'converged' if ok else 'NOT converged'}: L1 error estimate {estimate:.2e} "
              f"{'<=' if ok else '>'} rtol {rtol:.1e} with {h.size} cells ({how} solution; finest grid "
              f"{fine['density'].size} cells, {fine['n_steps']} TR-BDF2 steps; "
              f"{len(history)} grid{'s' if len(history) > 1 else ''})")
    if not ok and not fixed:
        status += f"; stopped at max_cells={max_cells}/max_refinements={max_refinements}"
    diagnostics = {
        "n_cells": int(h.size),
        "n_steps": int(fine["n_steps"]),
        "finest_cells": int(fine["density"].size),
        "returned_solution": best["kind"],
        "tau0": float(fine["tau0"]),
        "tau_end": problem.tau_end,
        "p_max": float(p_max),
        "tail_mass_bound": tail,
        "absorbing": absorbing,
        "wall_floor": floor,
        "floor_mass": float(fine.get("floor_mass", 0.0)),
        "floor_edge": best["floor_edge"],
        "clipped_mass": clipped,
        "min_density_during_run": fine["min_density"],
        "mass_error": mass - 1.0,
        "mean_error": mean - problem.mean_pressure if problem.drift is None else float("nan"),
        "coarse_zero_weight": coarse["zero_weight"],
        "extrapolated_cell_mass": mf + (mf - mc) / 3.0,
        "extrapolated_zero_weight": fine["zero_weight"] + (fine["zero_weight"] - coarse["zero_weight"]) / 3.0,
        "coarse_edges": edges[::2] if best["kind"] == "fine" else edges,  # where extrapolated_cell_mass lives
        "refinements": history,
        "jit_compile_time": compile_time,
        "time_scheme": "TR-BDF2",
        "wall_closure": wall_closure,
        "autonomous": problem.autonomous,
    }
    return PressureDistribution(
        p=x, density=density, weights=h, zero_weight=zero_weight,
        mean_pressure=problem.mean_pressure, variance=problem.variance, backend="native",
        success=bool(ok), message=status, error_estimate=float(estimate), wall_time=wall,
        diagnostics=diagnostics, edges=edges,
    )
