"""Grid and initial condition shared by the finite-volume backends.

Two helpers, used by the native, py-pde and FiPy backends alike so that their
results are comparable cell by cell:

* :func:`domain_edges` -- cell edges on ``[0, p_max]`` (``p_max`` from
  :meth:`FokkerPlanckProblem.upper_bound`), uniform or refined near ``p = 0``
  and near ``mean_pressure`` by a smooth analytic stretching, with the known
  non-smooth points of the diffusivity (e.g. the jump of the seed cutoff at
  ``p_c``) placed exactly on edges.
* :func:`short_time_start` -- the initial ``delta(p - p0)`` represented by the
  short-time analytic solution at a small ``tau0``: a Gaussian of variance
  ``2 f(p0) tau0`` (mean ``p0 + a(p0) tau0``) minus its mirror image about the
  absorbing wall ``p = 0`` (exactly Persson's mirror Gaussian for ``f = 1``),
  cell-averaged exactly with the normal CDF, then tilted so that the discrete
  mass and mean on the grid are exact.  Because the cell averages are exact
  integrals, nothing jumps when the grid shifts relative to ``p0``.

Units: pressures in the units of ``mean_pressure``; ``tau`` in pressure squared.
"""
from __future__ import annotations

from typing import Iterable, Optional, Sequence, Tuple

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from ..problem import FokkerPlanckProblem

Array = NDArray[np.float64]

__all__ = [
    "domain_edges",
    "short_time_start",
    "breakpoints_of",
    "is_absorbing",
    "tail_mass_for",
    "cell_centres",
    "adapted_edges",
    "wall_floor",
]

#: width of the short-time Gaussian in units of the local cell width at ``p0``
START_WIDTH_CELLS = 3.0


def tail_mass_for(rtol: float) -> float:
    """Probability allowed beyond ``p_max`` for a requested ``rtol``.

    ``1e-3 rtol``, clipped to ``[1e-15, 1e-8]``: the no-flux wall at ``p_max``
    reflects this mass, an L1 error of at most about twice it.
    """
    return float(np.clip(1e-3 * float(rtol), 1e-15, 1e-8))


def cell_centres(edges: Array) -> Array:
    """Midpoints of the cells (units of pressure)."""
    edges = np.asarray(edges, dtype=float)
    return 0.5 * (edges[1:] + edges[:-1])


def breakpoints_of(problem: FokkerPlanckProblem) -> list[float]:
    """Known non-smooth points of the diffusivity (units of pressure).

    Collected from ``problem.metadata["breakpoints"]`` and, for a
    :class:`~diffusion_pr.models.PressureFactor`, from the cutoff's ``p_c``
    (jump of the seed cutoff, kinks of the C1/C2 switches) and the tail's
    ``p_t`` (kink of ``max(1, p/p_t)``).  Only points inside ``(0, p_max)``
    matter; callers filter.
    """
    pts: list[float] = []
    meta = problem.metadata.get("breakpoints") if isinstance(problem.metadata, dict) else None
    if meta is not None:
        pts.extend(float(x) for x in np.atleast_1d(meta))
    f = problem.diffusivity
    for part in (getattr(f, "cutoff", None), getattr(f, "tail", None), f):
        for attr in ("p_c", "p_t"):
            val = getattr(part, attr, None)
            if val is not None and np.isfinite(val) and val > 0:
                # LinearTail (1 + p/p_t) is smooth: no breakpoint
                if attr == "p_t" and type(part).__name__ == "LinearTail":
                    continue
                pts.append(float(val))
    return sorted(set(pts))


def is_absorbing(problem: FokkerPlanckProblem) -> bool:
    """Whether probability reaches ``p = 0`` in finite ``tau`` (Feller's exit boundary).

    Uses the cutoff's ``absorbing`` attribute when the diffusivity is a
    :class:`~diffusion_pr.models.PressureFactor`; otherwise estimates the
    exponent ``k`` of ``f ~ p^k`` at the wall from two probes
    (``1e-8 p0``, ``1e-7 p0``): ``k < 1.5`` (``f(0+) > 0`` or ``f ∝ p``, the
    Feller case) counts as absorbing; ``f ~ p^2`` or faster (the smooth
    cutoffs) does not -- there mass only creeps exponentially close to 0.
    This flag steers the wall closure and the error metric; a drift towards
    the wall can absorb mass in either case.
    """
    cut = getattr(problem.diffusivity, "cutoff", None)
    if cut is not None and hasattr(cut, "absorbing"):
        return bool(cut.absorbing)
    p0 = problem.mean_pressure
    probe = np.array([1e-8 * p0, 1e-7 * p0])
    f1, f2 = problem.f(probe, 0.0)
    if f1 <= 0.0 or f2 <= 0.0:
        return False
    return bool(np.log(f2 / f1) / np.log(10.0) < 1.5)


def wall_floor(problem: FokkerPlanckProblem) -> float:
    """Pressure below which probability is treated as the non-contact peak.

    For a non-absorbing pressure factor (``f ~ A p^k`` with ``k >= 2`` at the
    wall, e.g. the seed cutoff and the C1/C2 switches) no mass reaches
    ``p = 0`` in finite ``tau``, but it creeps towards it: for ``k = 2``,
    ``ln p`` drifts down by ``A tau`` (geometric Brownian motion), for
    ``k > 2`` ``p`` falls like ``(A tau)^(-1/(k-2))``.  The grid resolves this
    creeping peak logarithmically down to the returned floor::

        p_floor = max(FLOOR_REL * p_ref, p_ref * exp(-(A tau + 8 sqrt(2 A tau) + 10)))   (k ~ 2)
        p_floor = max(FLOOR_REL * p_ref, 1e-3 (A tau_end)^(-1/(k-2)))                     (k > 2)

    with ``p_ref = min(p0, final width, breakpoints)`` and ``A``, ``k`` from
    two probes of ``f`` at ``1e-4`` and ``1e-3 p_ref``.  Mass that goes below
    the floor drains into ``zero_weight`` through the first cell (``f P = 0``
    at ``p = 0``): physically it lies below ``FLOOR_REL`` (1e-12) times the
    cutoff scale, a non-contact region in any measurable sense.  Units of
    pressure.
    """
    p0 = problem.mean_pressure
    bps = [b for b in breakpoints_of(problem) if b > 0.0]
    p_ref = min([p0, _final_width(problem)] + bps)
    p1, p2 = 1e-4 * p_ref, 1e-3 * p_ref
    f1, f2 = problem.f(np.array([p1, p2]), 0.0)
    floor = FLOOR_REL * p_ref
    if f1 <= 0.0 or f2 <= 0.0:
        return floor
    k = float(np.log(f2 / f1) / np.log(p2 / p1))
    amp = f2 / p2 ** k
    tau = problem.tau_end
    if k < 1.5:
        return floor
    if k < 2.5:
        at = amp * tau * p_ref ** (k - 2.0)
        expo = at + 8.0 * np.sqrt(2.0 * at) + 10.0
        return float(max(floor, p_ref * np.exp(-min(expo, 700.0))))
    return float(max(floor, 1e-3 * (amp * tau) ** (-1.0 / (k - 2.0))))


def _final_width(problem: FokkerPlanckProblem) -> float:
    """Width ``sqrt(2 tau_end f(p0))`` of the final distribution (pressure)."""
    p0 = problem.mean_pressure
    f0 = float(problem.f(np.array([p0]), 0.0)[0])
    probe = np.linspace(0.0, p0 + 6.0 * np.sqrt(problem.variance), 257)[1:]
    f_max = float(np.max(problem.f(probe, 0.0)))
    f_typ = max(f0, 0.25 * f_max, 1e-12)
    return float(np.sqrt(2.0 * problem.tau_end * f_typ))


#: shares of the cells: uniform, logarithmic near 0, broad Gaussian, narrow peak
GRID_WEIGHTS = (0.05, 0.2, 0.7, 0.05)
#: the same for non-absorbing ``f`` (smooth cutoffs): more cells in the log share
GRID_WEIGHTS_NON_ABSORBING = (0.05, 0.3, 0.6, 0.05)
#: probability below ``FLOOR_REL`` times the cutoff scale counts as non-contact
FLOOR_REL = 1e-12
#: width of the broad Gaussian share in final widths (``sqrt(3)``: ``h ~ P^(-1/3)``)
BROAD_WIDTH = 2.0
#: width of the narrow share around ``p0`` in final widths
PEAK_WIDTH = 0.25


def _erf_share(p: Array, centre: float, width: float, p_max: float) -> Array:
    lo = ndtr(-centre / width)
    hi = ndtr((p_max - centre) / width)
    return (ndtr((p - centre) / width) - lo) / (hi - lo)


def _stretch_map(p: Array, p_max: float, p0: float, p_s: float, width: float,
                 weights: Optional[Tuple[float, float, float, float]] = None) -> Array:
    """Monotone map ``xi(p)`` from ``[0, p_max]`` onto ``[0, 1]``.

    ``xi = w_u p/p_max + w_0 log(1 + p/p_s)/log(1 + p_max/p_s)
    + w_p [Phi((p - p0)/w_pk) - Phi(-p0/w_pk)] / norm`` -- a uniform part, a
    logarithmic part (cells of width about ``(p + p_s)`` times a constant near
    the wall) and an error-function part (extra cells within ``w_pk`` of
    ``p0``).  Edges are the pre-images of a uniform ``xi`` grid.
    """
    w_u, w_0, w_g, w_p = GRID_WEIGHTS if weights is None else weights
    return (w_u * p / p_max
            + w_0 * np.log1p(p / p_s) / np.log1p(p_max / p_s)
            + w_g * _erf_share(p, p0, max(BROAD_WIDTH * width, 1e-3 * p_max), p_max)
            + w_p * _erf_share(p, p0, max(PEAK_WIDTH * width, 1e-3 * p_max), p_max))


def _invert(targets: Array, fun, p_max: float, p_min_scale: float) -> Array:
    """Solve ``fun(p) = targets`` on ``[0, p_max]`` for a smooth increasing ``fun``.

    Piecewise-linear inverse from a dense sample (uniform plus geometric down
    to ``p_min_scale``), then safeguarded Newton steps with a centred
    difference derivative: converged to ~1e-13 relative in 3-4 passes.
    """
    m = max(4 * targets.size, 2048)
    sample = np.unique(np.concatenate((np.linspace(0.0, p_max, m),
                                       np.geomspace(max(p_min_scale, 1e-300), p_max, m))))
    xs = fun(sample)
    p = np.interp(targets, xs, sample)
    for _ in range(4):
        d = 1e-7 * np.maximum(p, p_min_scale)
        deriv = (fun(p + d) - fun(np.maximum(p - d, 0.0))) / (p + d - np.maximum(p - d, 0.0))
        step = (fun(p) - targets) / np.maximum(deriv, 1e-300)
        p_new = np.clip(p - step, 0.0, p_max)
        if np.max(np.abs(p_new - p)) <= 1e-13 * p_max:
            p = p_new
            break
        p = p_new
    return p


def domain_edges(
    problem: FokkerPlanckProblem,
    n_cells: int,
    *,
    rtol: float,
    uniform: bool = False,
    breakpoints: Optional[Iterable[float]] = None,
    align: int = 2,
    p_max: Optional[float] = None,
) -> Array:
    """Cell edges of the finite-volume grid on ``[0, p_max]``.

    Parameters
    ----------
    problem : FokkerPlanckProblem
        The problem; gives ``p0``, ``tau_end``, ``f`` and ``p_max``.
    n_cells : int
        Number of cells (>= 8).
    rtol : float
        Requested accuracy; sets the truncated tail mass
        (:func:`tail_mass_for`) and so ``p_max = problem.upper_bound(...)``.
    uniform : bool
        Equal cells if True.  Otherwise (default) the smooth stretching of
        :func:`_stretch_map`: half the cells uniform, 20 % logarithmically
        graded towards ``p = 0`` down to the scale
        ``p_s = 0.1 min(p0, width, breakpoints)`` (non-absorbing ``f``:
        down to :func:`wall_floor`, with 30 % of the cells), the rest in a
        broad Gaussian share of width ``2 width`` and a narrow one of width
        ``width/4`` around ``p0`` (``width = sqrt(2 tau_end f)``, the final
        spread); see :data:`GRID_WEIGHTS`.
    breakpoints : iterable of float, optional
        Pressures (units of pressure) that must be cell edges, e.g. where
        ``f`` jumps; defaults to :func:`breakpoints_of`.  With the Ito flux
        ``f P`` is continuous there and ``P`` may jump between two cells.
    align : int
        Breakpoints are put on edges whose index is a multiple of ``align``
        (default 2), so ``edges[::2]`` -- the coarse grid of a nested pair --
        contains them too.  Done by a piecewise-linear reparametrization of
        ``xi`` (the cell width changes by a factor ``1 + O(1/n_cells)``).
    p_max : float, optional
        Upper end (units of pressure); default ``problem.upper_bound(tail_mass_for(rtol))``.

    Returns
    -------
    ndarray
        ``n_cells + 1`` strictly increasing edges, ``edges[0] = 0``,
        ``edges[-1] = p_max``.
    """
    n_cells = int(n_cells)
    if n_cells < 8:
        raise ValueError(f"n_cells must be >= 8; got n_cells={n_cells}")
    if p_max is None:
        p_max = problem.upper_bound(tail_mass=tail_mass_for(rtol))
    p_max = float(p_max)
    p0 = problem.mean_pressure
    if breakpoints is None:
        breakpoints = breakpoints_of(problem)
    bps = sorted(float(b) for b in breakpoints if 0.0 < float(b) < p_max)

    p_s = 1e-6 * p_max
    if uniform:
        def fun(p: Array) -> Array:
            return np.asarray(p) / p_max
    else:
        width = _final_width(problem)
        scales = [p0, width] + bps
        p_s = 0.1 * min(scales)
        weights = GRID_WEIGHTS
        if not is_absorbing(problem):
            p_s = min(p_s, 0.1 * wall_floor(problem))
            weights = GRID_WEIGHTS_NON_ABSORBING

        def fun(p: Array) -> Array:
            return _stretch_map(np.asarray(p, dtype=float), p_max, p0, p_s, width, weights)

    xi_b = [float(fun(np.array(b))) for b in bps]
    targets_x, snaps = _aligned_targets(xi_b, n_cells, align)
    edges = _invert(targets_x[1:-1], fun, p_max, 0.1 * p_s)
    edges = np.concatenate(([0.0], edges, [p_max]))
    return _finish_edges(edges, snaps, bps, p_max)


def _aligned_targets(xi_b: list, n_cells: int, align: int) -> Tuple[Array, list]:
    """Map values of the edges so that breakpoints land on edges with index % align == 0.

    ``xi_b``: the map value of each breakpoint.  Returns the ``n_cells + 1``
    map values of the edges (a piecewise-linear reparametrization of a
    uniform grid, cell widths change by ``1 + O(1/n_cells)``) and a list of
    ``(edge index, breakpoint number)`` to set exactly afterwards.
    """
    step = align / n_cells if n_cells % align == 0 else 1.0 / n_cells
    nodes_x, nodes_t, snaps = [0.0], [0.0], []
    for j, xb in enumerate(xi_b):
        t = round(xb / step) * step
        if t <= nodes_t[-1] or t >= 1.0 or xb <= nodes_x[-1]:
            continue  # two breakpoints in one coarse cell: keep the first only
        nodes_x.append(xb)
        nodes_t.append(t)
        snaps.append((int(round(t * n_cells)), j))
    nodes_x.append(1.0)
    nodes_t.append(1.0)
    targets_t = np.linspace(0.0, 1.0, n_cells + 1)
    return np.interp(targets_t, nodes_t, nodes_x), snaps


def _finish_edges(edges: Array, snaps: list, bps: list, p_max: float) -> Array:
    for k, j in snaps:
        edges[k] = bps[j]
    edges[0], edges[-1] = 0.0, p_max
    if np.any(np.diff(edges) <= 0.0):
        raise ValueError("could not build a strictly increasing grid "
                         f"(n_cells={edges.size - 1}, p_max={p_max:.6g}, breakpoints={bps})")
    return edges


def adapted_edges(
    coarse_edges: Array,
    cell_error: Array,
    target: float,
    *,
    breakpoints: Sequence[float] = (),
    align: int = 2,
    min_share: float = 0.25,
    min_growth: float = 0.5,
    max_growth: float = 8.0,
    max_cells: int = 2 ** 17,
) -> Array:
    """Fine edges of the next nested pair from the error of the last one.

    Equidistribution for a second-order scheme: the error of a coarse cell of
    width ``h`` behaves as ``w h^3`` (``w`` from the measured per-cell error
    ``e_j``: ``w_j = e_j / h_j^3``), so the L1 error ``sum w h^3`` for a
    given number of cells is smallest with the cell density
    ``g = 1/h ∝ w^(1/3)``; then ``error = (sum_j e_j^(1/3))^3 / N^2`` and
    ``N = sqrt((sum e^(1/3))^3 / target)`` coarse cells meet ``target``.  The
    indicator is spread over neighbouring cells (maximum over 5 cells, then
    a 5-cell mean of ``log g``) so that zero crossings of the error do not
    starve cells and the width varies smoothly, and every old cell keeps at
    least ``min_share`` of a uniform refinement.

    Parameters
    ----------
    coarse_edges : ndarray
        Coarse edges of the last pair (units of pressure).
    cell_error : ndarray
        Estimated L1 error of the fine solution in each coarse cell.
    target : float
        L1 error wanted from the next fine solution.
    breakpoints : sequence of float
        Pressures that must stay edges (with index % ``align`` == 0).
    align : int
        As in :func:`domain_edges`.
    min_share, min_growth, max_growth, max_cells : float, float, float, int
        Floor of the cell density (a share of the old grid's, so resolved
        regions stay resolved), bounds on the growth of the cell count per
        step, cap on the number of fine cells.

    Returns
    -------
    ndarray
        Edges of the next *fine* grid (its coarse grid is ``[::align]``).
    """
    from scipy.ndimage import maximum_filter1d, uniform_filter1d

    edges = np.asarray(coarse_edges, dtype=float)
    h = np.diff(edges)
    n_old = h.size
    e = np.maximum(np.asarray(cell_error, dtype=float), 0.0)
    e = maximum_filter1d(e, size=5, mode="nearest")
    if not np.all(np.isfinite(e)):
        raise ValueError("adapted_edges: non-finite cell errors")
    e = np.maximum(e, 1e-6 * max(float(e.max()), 1e-300))
    root = np.cbrt(e)
    total = float(root.sum())
    n_new = float(np.sqrt(total ** 3 / max(target, 1e-300)))
    n_new = float(np.clip(n_new, min_growth * n_old, max_growth * n_old))
    n_new = int(min(n_new, max_cells // align))
    n_new = max(n_new, 8)
    g = n_new * root / (h * total)
    g = np.maximum(g, min_share * (n_new / n_old) / h)
    g = np.exp(uniform_filter1d(np.log(g), size=5, mode="nearest"))
    cum = np.concatenate(([0.0], np.cumsum(g * h)))
    cum /= cum[-1]
    n_fine = align * n_new
    bps = sorted(float(b) for b in breakpoints if 0.0 < float(b) < edges[-1])
    xi_b = [float(np.interp(b, edges, cum)) for b in bps]
    targets, snaps = _aligned_targets(xi_b, n_fine, align)
    fine = np.interp(targets, cum, edges)
    return _finish_edges(fine, snaps, bps, float(edges[-1]))


def _normal_mass(a: Array, b: Array) -> Array:
    """``Phi(b) - Phi(a)`` for standardized bounds, accurate in both tails."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    upper = a > 0.0
    return np.where(upper, ndtr(-a) - ndtr(-b), ndtr(b) - ndtr(a))


def _tilt(mass: Array, x: Array, target_mass: float, target_mean: float) -> Array:
    """Exponential tilt ``m_i exp(alpha + beta (x_i - xbar)/s)`` with exact mass and mean.

    Newton on the two moment equations in standardized units (``s`` the
    spread of the cells holding mass), steps damped to ``|d beta| <= 0.5``;
    the tilt is tiny (the cell averages are exact integrals, only the
    point-mean ``sum x_i m_i`` is off by ``O(h^2)``), so 2-4 iterations reach
    round-off.  Keeps every cell positive.  If Newton fails (degenerate
    spreads) the masses are only rescaled to the target mass.
    """
    m = mass.copy()
    tot = m.sum()
    if tot <= 0.0 or target_mass <= 0.0:
        return m
    xbar = target_mean / target_mass
    mu = float(np.sum(x * m) / tot)
    spread = float(np.sqrt(max(np.sum((x - mu) ** 2 * m) / tot, 0.0)))
    if not spread > 0.0:
        return m * (target_mass / tot)
    y = (x - xbar) / spread
    live = m > 0.0
    m, y_l = m[live], y[live]
    goal1 = 0.0  # mean of y under the target: (target_mean - xbar * target_mass) / spread = 0
    alpha, beta = np.log(target_mass / tot), 0.0
    ok = False
    for _ in range(30):
        w = m * np.exp(alpha + beta * y_l)
        s0, s1, s2 = w.sum(), np.sum(w * y_l), np.sum(w * y_l * y_l)
        r0, r1 = s0 - target_mass, s1 - goal1
        det = s0 * s2 - s1 * s1
        if not np.isfinite(det) or det <= 0.0:
            break
        d_alpha = (s2 * r0 - s1 * r1) / det
        d_beta = (s0 * r1 - s1 * r0) / det
        if abs(d_beta) > 0.5:
            scale = 0.5 / abs(d_beta)
            d_alpha, d_beta = d_alpha * scale, d_beta * scale
        alpha -= d_alpha
        beta -= d_beta
        if abs(d_alpha) < 1e-15 and abs(d_beta) < 1e-15:
            ok = True
            break
        ok = abs(r0) <= 1e-15 * target_mass and abs(r1) <= 1e-15 * target_mass
    out = np.zeros_like(mass)
    if ok or (np.isfinite(alpha) and np.isfinite(beta) and abs(beta) < 10.0):
        out[live] = m * np.exp(alpha + beta * y_l)
        if np.all(np.isfinite(out)):
            return out
    return mass * (target_mass / tot)


def short_time_start(
    problem: FokkerPlanckProblem,
    edges: Array,
    *,
    width_cells: float = START_WIDTH_CELLS,
) -> Tuple[float, Array, float]:
    """Initial condition: the short-time analytic solution on the grid.

    For small ``tau0`` the solution from ``delta(p - p0)`` is a Gaussian of
    mean ``m = p0 + a(p0, 0) tau0`` and variance ``s^2 = 2 f(p0) tau0``;
    the absorbing wall is represented by its mirror image (Persson's mirror
    Gaussian, exact for ``f = 1``)::

        P(p, tau0) = phi(p; m, s^2) - phi(p; -m, s^2)      (p > 0),
        zero_weight0 = 1 - erf(m / (sqrt(2) s)).

    ``tau0`` is chosen so that ``s = width_cells * h(p0)`` (``h(p0)`` the width
    of the cell holding ``p0``), capped at ``tau_end / 10``: resolved by the
    grid, and small enough that the neglected ``O(f' tau0)`` skewness of the
    true short-time solution changes the final L1 distance by
    ``O((tau0 / tau_end)^2)``, which shrinks with the grid (so it is part of
    what the grid-refinement estimate measures).  Cell averages are exact
    differences of normal CDFs; an exponential tilt then makes the discrete
    mass ``sum h_i P_i = 1 - zero_weight0`` and the discrete mean
    ``sum h_i x_i P_i = m (1 - 0)`` (the wall peak adds no pressure) exact to
    round-off.  The finite-volume schemes of this package conserve both
    exactly from then on.  If ``f(p0) = 0`` the delta cannot spread:
    ``tau0 = 0`` and the mass is split between the two cells around ``p0``
    with the exact mean.

    Parameters
    ----------
    problem : FokkerPlanckProblem
        The problem (``p0``, ``f``, drift).
    edges : ndarray
        Cell edges (units of pressure), ``edges[0] = 0``.
    width_cells : float
        Standard deviation of the start in local cell widths (default 3).

    Returns
    -------
    tau0 : float
        Start time (pressure squared), ``0 <= tau0 <= tau_end / 10``.
    density : ndarray
        Cell-average density at ``tau0`` (1 / pressure), non-negative.
    zero_weight0 : float
        Probability already at ``p = 0`` (the mirror image's share).
    """
    edges = np.asarray(edges, dtype=float)
    h = np.diff(edges)
    x = cell_centres(edges)
    p0 = problem.mean_pressure
    k = int(np.clip(np.searchsorted(edges, p0) - 1, 0, h.size - 1))
    f0 = float(problem.f(np.array([p0]), 0.0)[0])
    a0 = float(problem.a(np.array([p0]), 0.0)[0])
    if f0 <= 0.0:
        tau0 = 0.0
        mass = np.zeros_like(h)
        j = int(np.clip(np.searchsorted(x, p0) - 1, 0, h.size - 2))
        w = (x[j + 1] - p0) / (x[j + 1] - x[j])
        w = float(np.clip(w, 0.0, 1.0))
        mass[j], mass[j + 1] = w, 1.0 - w
        return tau0, mass / h, 0.0
    s = width_cells * h[k]
    tau0 = min(s * s / (2.0 * f0), 0.1 * problem.tau_end)
    s = np.sqrt(2.0 * f0 * tau0)
    m = p0 + a0 * tau0
    if m <= 0.0:
        m = p0
    lo, hi = edges[:-1], edges[1:]
    mass = _normal_mass((lo - m) / s, (hi - m) / s) - _normal_mass((lo + m) / s, (hi + m) / s)
    mass = np.maximum(mass, 0.0)
    zero0 = float(ndtr(-m / s) * 2.0)  # = 1 - erf(m / (sqrt 2 s))
    target = 1.0 - zero0
    mass = _tilt(mass, x, target, m)
    return float(tau0), mass / h, zero0
