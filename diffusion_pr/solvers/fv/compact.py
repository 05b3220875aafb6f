"""The compact fourth-order scheme on the primitive ``M``: a fourth-order alternative to the engine's operator.

Not used by :func:`~diffusion_pr.solvers.fv.engine.solve_fv`. Built and measured for issue 10 as a route to faster
balanced closures: on the engine's own grids it needs 2.3-4.2x fewer cells than the engine's second-order scheme
with Richardson, at about 2x the cost per cell in its compiled loop, so a partial route at best (docs/closures.md,
"The compact scheme from the delta, and in compiled code"; ``benchmarks/compact_closure.py``). A tested
fourth-order solver of staged Fokker-Planck problems on ``M``, each part checked against an oracle of its own
(``tests/diffusion_pr/test_fv_compact.py``):

* :func:`hoc_bands`: the high-order compact (HOC) discretization of ``u_tau = A u'' + B u'`` on a uniform grid
  in a coordinate ``xi`` (Spotz and Carey, Numer. Methods Partial Differ. Equ. 17, 657 (2001),
  doi:10.1002/num.1032), ``P du/dtau = Q u`` with ``P`` and ``Q`` both tridiagonal, fourth order;
* :func:`expm_pencil`: ``exp(t P^-1 Q) y`` by CRAM in partial fractions, every shifted solve
  ``(t Q - theta P) x = P y`` tridiagonal (:func:`._compact_kernels.pencil_pfd`), with the derivative in a
  multiplier on which the pencil depends (the balance's Newton);
* :func:`index_coordinate` and :func:`with_derivatives`: the pencil's coefficients from a grid's nodes alone
  (the node index as the coordinate), so that any smooth grid family serves, the remapped ones included;
* :func:`absorbing_bottom`: the engine's absorbing wall as a one-sided first row (the kernel eliminates it in
  O(n));
* :func:`mean_weights`, :func:`stage_rows` and :func:`run_stages`: every stage of one grid, the balance included,
  in one compiled call (:func:`._compact_kernels.staged_run`);
* :func:`corrected_delta_start`: the start for ``delta(p - p0)``. The sampled step ``H(p - p0)`` costs the compact
  scheme its order: from it both the scheme and its Richardson ``(16 X(2N) - X(N))/15`` converge at second order
  (``benchmarks/fourth_order_space.py --skip 0 --start-shift 0``); corrected as here, at fourth.

For the probability below ``p``, ``M(p, tau)``, of ``Pr_tau = (f Pr)_pp - (a Pr)_p``:
``M_tau = f M_pp + (f_p - a) M_p``, and on a grid uniform in ``xi`` (``p = p(xi)``)
``A = f / p_xi^2`` and ``B = (f_p - a) / p_xi - f p_xixi / p_xi^3``. Pressures and ``xi`` in any consistent
units; ``tau`` in the inverse units of ``A / h^2``.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from .cram import pfd_coefficients

__all__ = ["hoc_bands", "expm_pencil", "corrected_delta_start", "absorbing_bottom", "index_coordinate",
           "with_derivatives", "mean_weights", "stage_rows", "run_stages"]


def hoc_bands(h: float, a: tuple, b: tuple) -> tuple:
    """The bands of ``P`` and ``Q`` of the HOC scheme for ``u_tau = A u'' + B u'``.

    Parameters
    ----------
    h : float
        The grid spacing in ``xi`` (> 0).
    a, b : tuple of three arrays
        ``(A, A', A'')`` and ``(B, B', B'')`` at the interior nodes (``n - 2`` values each; derivatives in ``xi``).
        ``A > 0``.

    Returns
    -------
    ((pl, pd, pu), (ql, qd, qu))
        Lower, diagonal and upper bands of ``P`` and ``Q`` on all ``n`` nodes; the two end rows are
        ``u_tau = 0`` (``P`` row 1, ``Q`` row 0: ``u`` held at both ends).

    Notes
    -----
    The central differences' ``h^2`` terms, ``h^2/12 (A u'''' + 2 B u''')``, written through the equation itself
    (``u'''`` and ``u''''`` from derivatives of ``A u'' + B u' = u_tau``) give

    ``P = 1 + h^2/12 (delta^2 + beta delta_1)``, ``Q = (A + h^2 kappa/12) delta^2 + (B + h^2 gamma/12) delta_1``,

    ``beta = (B - 2 A')/A``, ``gamma = B'' + beta B'``, ``kappa = 2 B' + A'' + beta (A' + B)``, with
    ``delta^2`` and ``delta_1`` the central second and first differences.
    """
    if not h > 0.0:
        raise ValueError(f"h must be > 0; got h={h!r}")
    (A, A1, A2), (B, B1, B2) = (tuple(np.asarray(v, dtype=float) for v in a),
                                tuple(np.asarray(v, dtype=float) for v in b))
    if not np.all(A > 0.0):
        raise ValueError(f"A must be > 0 at every interior node; got min A = {float(np.min(A))!r}")
    beta = (B - 2.0 * A1) / A
    gamma = B2 + beta * B1
    kappa = 2.0 * B1 + A2 + beta * (A1 + B)
    n = A.size + 2
    pl, pd, pu = np.zeros(n - 1), np.ones(n), np.zeros(n - 1)
    ql, qd, qu = np.zeros(n - 1), np.zeros(n), np.zeros(n - 1)
    pl[:-1] = 1.0 / 12.0 - beta * h / 24.0  # rows 1 .. n-2, column k-1
    pd[1:-1] = 5.0 / 6.0
    pu[1:] = 1.0 / 12.0 + beta * h / 24.0  # rows 1 .. n-2, column k+1
    d2 = (A + h * h * kappa / 12.0) / h ** 2
    d1 = (B + h * h * gamma / 12.0) / (2.0 * h)
    ql[:-1] = d2 - d1
    qd[1:-1] = -2.0 * d2
    qu[1:] = d2 + d1
    return (pl, pd, pu), (ql, qd, qu)


def _stencil_weights(offsets: np.ndarray, order: int) -> np.ndarray:
    """Weights ``w`` with ``sum_k w_k v(x + offsets_k) = v^(order)(x)`` for polynomials of degree < len(offsets)."""
    vander = np.array([offsets.astype(float) ** i for i in range(offsets.size)])
    rhs = np.zeros(offsets.size)
    rhs[order] = math.factorial(order)
    return np.linalg.solve(vander, rhs)


def index_coordinate(p_nodes: np.ndarray) -> tuple:
    """``(p_xi, p_xixi)`` at every node of a grid given by its nodes, with the node index as the coordinate
    (``h = 1``): five-point differences, centred inside, one-sided at the two nodes next to each end; exact for
    quartics, so fourth order on a grid that is a smooth map of a uniform one.

    With these the compact scheme needs nothing but the nodes: ``A = f / p_xi^2`` and
    ``B = (f_p - a) / p_xi - f p_xixi / p_xi^3`` at the nodes, and their derivatives by :func:`with_derivatives`.

    Parameters
    ----------
    p_nodes : array (n >= 5,)
        Increasing node positions (pressure units).
    """
    p = np.asarray(p_nodes, dtype=float)
    if p.ndim != 1 or p.size < 5 or not np.all(np.diff(p) > 0.0):
        raise ValueError(f"p_nodes must be increasing with at least 5 nodes; got shape {p.shape}")
    n = p.size
    d1, d2 = np.empty(n), np.empty(n)
    inner = np.array([-2, -1, 0, 1, 2])
    w1, w2 = _stencil_weights(inner, 1), _stencil_weights(inner, 2)
    windows = np.lib.stride_tricks.sliding_window_view(p, 5)
    d1[2:-2], d2[2:-2] = windows @ w1, windows @ w2
    for i in (0, 1, n - 2, n - 1):
        lo = min(max(i - 2, 0), n - 5)
        offsets = np.arange(lo, lo + 5) - i
        d1[i] = _stencil_weights(offsets, 1) @ p[lo:lo + 5]
        d2[i] = _stencil_weights(offsets, 2) @ p[lo:lo + 5]
    return d1, d2


def with_derivatives(values: np.ndarray) -> tuple:
    """``(v, v', v'')`` at the interior nodes from a coefficient's values at all nodes (the last axis: one row per
    stage may be given), in the node index (``h = 1``), by central differences: second order, which is all
    :func:`hoc_bands` needs of ``A'``, ``A''``, ``B'`` and ``B''`` (``h^2`` multiplies them; measured on the heat
    kernel: the scheme keeps ratios 15.6-16.0 per halving, ``tests/diffusion_pr/test_fv_compact.py``)."""
    v = np.asarray(values, dtype=float)
    return (np.ascontiguousarray(v[..., 1:-1]), 0.5 * (v[..., 2:] - v[..., :-2]),
            v[..., 2:] - 2.0 * v[..., 1:-1] + v[..., :-2])


def corrected_delta_start(n_nodes: int, j: int, shift: float = 1.0 / 24.0) -> np.ndarray:
    """``M`` at the start for ``delta(p - p0)``, ``p0`` at node ``j`` with the same spacing in ``xi`` on both
    sides: the sampled step (``M(p0) = 1/2``) with the two neighbours of ``p0`` moved outwards by 1/24.

    That is ``(1 - h^2/12 delta^2) H`` at the nodes, ``P^-1 H`` to the order that matters: the scheme's nodal
    values stand for ``P^-1`` of the function's samples, and initial data smoothed to the scheme's order keep it
    (Kreiss, Thomee and Widlund, Comm. Pure Appl. Math. 23, 241 (1970), doi:10.1002/cpa.3160230207). Measured
    (``benchmarks/fourth_order_space.py --skip 0``): the balanced closures' compact ``R4`` at 2e-8 to 6e-8 on 320
    cells from this start, 3e-4 from the sampled step.

    Parameters
    ----------
    n_nodes : int
        Nodes of the grid (>= 5).
    j : int
        The node at ``p0`` (``2 <= j <= n_nodes - 3``: both neighbours interior).
    shift : float
        The neighbours' shift: 1/24 keeps fourth order; other values are for measuring that (0, the sampled step,
        1/16 and 1/12 give second order).
    """
    if not (isinstance(n_nodes, (int, np.integer)) and n_nodes >= 5):
        raise ValueError(f"n_nodes must be an integer >= 5; got n_nodes={n_nodes!r}")
    if not (isinstance(j, (int, np.integer)) and 2 <= j <= n_nodes - 3):
        raise ValueError(f"j must be an integer in [2, {n_nodes - 3}]; got j={j!r}")
    M = np.zeros(n_nodes)
    M[j] = 0.5
    M[j + 1:] = 1.0
    M[j - 1] -= shift
    M[j + 1] += shift
    return M


def absorbing_bottom(h: float, a_bottom: float) -> tuple:
    """``Q``'s first row for an absorbing bottom at node 0 (``Pr = 0`` there: ``M_xi = 0``, and ``M_tau = A M''``).

    ``M''`` from ``M_0 .. M_3`` given ``M' = 0``, to third order: ``M_k - M_0 = h^2 (k^2/2 M'' + h k^3/6 M''' +
    h^2 k^4/24 M'''')`` for ``k = 1, 2, 3``, solved for ``M''``. ``P``'s first row stays ``(1, 0)``.

    Parameters
    ----------
    h : float
        The grid spacing in ``xi`` (> 0).
    a_bottom : float
        ``A`` at node 0 (>= 0).

    Returns
    -------
    (q00, q01, q_row0)
        ``Q``'s diagonal and upper entries of row 0, and its entries in columns 2 and 3 (:func:`expm_pencil`'s
        ``q_row0``).
    """
    if not h > 0.0:
        raise ValueError(f"h must be > 0; got h={h!r}")
    if not a_bottom >= 0.0:
        raise ValueError(f"a_bottom must be >= 0; got a_bottom={a_bottom!r}")
    row = _one_sided_weights() * a_bottom / h ** 2
    return -float(row.sum()), float(row[0]), row[1:].copy()


@functools.lru_cache(maxsize=1)
def _one_sided_weights() -> np.ndarray:
    """The weights of ``M'' h^2 ~ sum_k c_k (M_k - M_0)``, ``k = 1, 2, 3``, given ``M' = 0`` (:func:`absorbing_bottom`;
    solved once, read-only)."""
    k = np.arange(1.0, 4.0)
    weights = np.linalg.solve(np.array([k ** 2 / 2, k ** 3 / 6, k ** 4 / 24]), np.array([1.0, 0.0, 0.0]))
    weights.setflags(write=False)
    return weights


def expm_pencil(p_bands: tuple, q_bands: tuple, t: float, y: np.ndarray, *, order: int = 16,
                q_row0: np.ndarray | None = None, derivative: tuple | None = None) -> tuple:
    """``exp(t P^-1 Q) y`` (and its derivative in a multiplier) by CRAM in partial fractions.

    Parameters
    ----------
    p_bands, q_bands : tuple of three float arrays
        ``(lower, diag, upper)`` of ``P`` and ``Q`` (:func:`hoc_bands`). ``P^-1 Q`` must have its spectrum on or
        near the negative real axis, where CRAM holds (a diffusion operator: the HOC pencil of a problem with
        ``A > 0`` on a resolved grid).
    t : float
        The time step (>= 0).
    y : array (n,)
        The state.
    order : int
        10, 12 or 16 (:func:`.cram.pfd_coefficients`).
    q_row0 : array (2,), optional
        ``Q``'s first row beyond the band, columns 2 and 3 (:func:`absorbing_bottom`; ``y`` of size >= 4).
    derivative : tuple, optional
        ``(P_a bands, Q_a bands)`` or ``(P_a bands, Q_a bands, Q_a's q_row0)``: also return the derivative of the
        result in the multiplier ``a``.

    Returns
    -------
    (x, dx)
        ``dx`` is None without ``derivative``.

    Raises
    ------
    ValueError
        On bad input; RuntimeError where a pivot vanished (no row interchanges: the pencil's matrices are
        diagonally dominant on resolved grids).
    """
    from ._compact_kernels import pencil_pfd

    theta, res, r_inf, _ = pfd_coefficients(order)
    pb = tuple(np.ascontiguousarray(v, dtype=float) for v in p_bands)
    qb = tuple(np.ascontiguousarray(v, dtype=float) for v in q_bands)
    y = np.ascontiguousarray(y, dtype=float)
    n = y.size
    for name, bands in (("p_bands", pb), ("q_bands", qb)):
        if [v.size for v in bands] != [n - 1, n, n - 1]:
            raise ValueError(f"{name} must be (lower, diag, upper) of sizes ({n - 1}, {n}, {n - 1}) for y of size "
                             f"{n}; got sizes {[v.size for v in bands]}")
    if not (np.isfinite(t) and t >= 0.0):
        raise ValueError(f"t must be finite and >= 0; got t={t!r}")
    row0 = np.zeros(2) if q_row0 is None else np.ascontiguousarray(q_row0, dtype=float)
    if row0.shape != (2,) or (q_row0 is not None and n < 4):
        raise ValueError(f"q_row0 must have 2 entries (columns 2 and 3) and y at least 4; got shape {row0.shape} "
                         f"and y of size {n}")
    if derivative is None:
        da, dq, drow0 = pb, qb, row0
    else:
        da, dq = (tuple(np.ascontiguousarray(v, dtype=float) for v in part) for part in derivative[:2])
        drow0 = np.ascontiguousarray(derivative[2], dtype=float) if len(derivative) > 2 else np.zeros(2)
    x, dx, info = pencil_pfd(*pb, *qb, row0, float(t), y, res, theta, float(r_inf), derivative is not None, *da,
                             *dq, drow0)
    if info:
        raise RuntimeError(f"expm_pencil: the pivot of row {info} vanished (t={t!r})")
    return x, (dx if derivative is not None else None)


def mean_weights(p_nodes: np.ndarray) -> np.ndarray:
    """Weights ``ww`` with ``ww . M`` the mean pressure of the distribution whose probability below ``p`` is ``M``
    at the nodes, the weight ``M_0`` below the first node counted at ``p = 0`` (the zero weight; where ``M_0 = 0``,
    it does not matter).

    ``<p> = p_n M_n - p_0 M_0 - int_{p_0}^{p_n} M dp``, the integral with ``M`` cubic through the four nearest nodes
    on every interval (fourth order), each interval's Lagrange integrals in its own coordinate (in absolute ``p``
    the monomials cancel catastrophically on fine grids: a false error floor of 1e-5 was measured so).

    Parameters
    ----------
    p_nodes : array (n >= 4,)
        Increasing node positions (pressure units); the weights carry those units.
    """
    p = np.asarray(p_nodes, dtype=float)
    if p.ndim != 1 or p.size < 4 or not np.all(np.diff(p) > 0.0):
        raise ValueError(f"p_nodes must be increasing with at least 4 nodes; got shape {p.shape}")
    n = p.size - 1
    k = np.arange(n)
    j0 = np.clip(k - 1, 0, n - 3)
    idx = j0[:, None] + np.arange(4)
    width = p[k + 1] - p[k]
    ts = (p[idx] - p[k][:, None]) / width[:, None]  # the interval is [0, 1] in its own coordinate
    # sum_j w_j t_j^m = int_0^1 t^m dt = 1/(m + 1), m = 0..3: the Lagrange basis' integrals
    vander = ts[:, None, :] ** np.arange(4)[None, :, None]
    w = np.linalg.solve(vander, np.broadcast_to(1.0 / np.arange(1.0, 5.0), (n, 4))[..., None])[..., 0]
    omega = np.zeros(n + 1)
    np.add.at(omega, idx, w * width[:, None])
    ww = -omega
    ww[-1] += p[-1]
    ww[0] -= p[0]
    return ww


def stage_rows(p_nodes: np.ndarray, f: np.ndarray, f_p: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple:
    """The pencil's coefficient rows of every stage from values at the nodes, the node index as the coordinate.

    For ``Pr_tau = (f Pr)_pp - (a Pr)_p`` with ``a = b - A w`` (``A`` a stage's balance multiplier):
    ``A_coef = f / p_xi^2``, ``B = B_f + A B_w`` with ``B_f = (f_p - b) / p_xi - f p_xixi / p_xi^3`` and
    ``B_w = w / p_xi`` (:func:`index_coordinate`, :func:`with_derivatives`).

    Parameters
    ----------
    p_nodes : array (n,)
        The nodes (pressure).
    f, f_p, b, w : arrays (stages, n)
        The diffusivity [pressure^2 per unit tau], its derivative in ``p`` [pressure per unit tau], the drift
        [pressure per unit tau] and the balance drift [pressure per unit tau per unit ``A``] at the nodes, one row per
        stage.

    Returns
    -------
    (a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, a_bottom)
        Rows (stages, n - 2) at the interior nodes, and ``A_coef`` at node 0 per stage (the absorbing bottom's
        :func:`absorbing_bottom`).
    """
    p_xi, p_xixi = index_coordinate(p_nodes)
    f, f_p, b, w = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (f, f_p, b, w))
    shapes = {v.shape for v in (f, f_p, b, w)}
    if len(shapes) != 1 or f.shape[1] != p_xi.size:
        raise ValueError(f"f, f_p, b and w must be (stages, {p_xi.size}) arrays alike; got shapes "
                         f"{[v.shape for v in (f, f_p, b, w)]}")
    if not np.all(f[:, 1:-1] > 0.0):
        raise ValueError("f must be > 0 at every interior node")
    a_coef = f / p_xi ** 2
    b_f = (f_p - b) / p_xi - f * p_xixi / p_xi ** 3
    b_w = w / p_xi

    return (*with_derivatives(a_coef), *with_derivatives(b_f), *with_derivatives(b_w),
            np.ascontiguousarray(a_coef[:, 0]))


def run_stages(rows: tuple, durations: np.ndarray, M: np.ndarray, *, weights: np.ndarray, p0: float,
               balanced: np.ndarray | bool = True, absorbing: bool = True, mean_tol: float = 1e-10,
               lin_tol: float = 1e-5, max_iter: int = 30, order: int = 16) -> tuple:
    """Every stage of one grid by the compact scheme (:func:`._compact_kernels.staged_run`), index coordinate.

    Parameters
    ----------
    rows : tuple
        :func:`stage_rows`' output.
    durations : array (stages,)
        Each stage's duration in ``tau`` (>= 0).
    M : array (n,)
        The start (e.g. :func:`corrected_delta_start`).
    weights : array (n,)
        :func:`mean_weights` of the nodes.
    p0 : float
        The mean a balanced stage ends at (pressure, > 0).
    balanced : bool or array of bool
        Which stages carry the balance.
    absorbing : bool
        The bottom absorbs (:func:`absorbing_bottom`); else ``M_0`` is held (a closed bottom).
    mean_tol, lin_tol : float
        The balance's tolerance on the miss of the mean and the miss below which the last Newton step is taken to
        first order, both relative to ``p0``.

    Returns
    -------
    (M, multipliers, info)
        ``info``: the exponentials and Newton steps taken.

    Raises
    ------
    RuntimeError
        Where a stage fails (a vanished pivot, or the balance not converging): the stage and the reason.
    """
    from ._compact_kernels import staged_run

    theta, res, r_inf, _ = pfd_coefficients(order)
    a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, a_bottom = rows
    dt = np.ascontiguousarray(durations, dtype=float)
    if dt.ndim != 1 or dt.size != a.shape[0] or not np.all(np.isfinite(dt) & (dt >= 0.0)):
        raise ValueError(f"durations must be {a.shape[0]} finite values >= 0; got {durations!r}")
    if not (np.isfinite(p0) and p0 > 0.0):
        raise ValueError(f"p0 must be finite and > 0; got p0={p0!r}")
    flags = np.broadcast_to(np.asarray(balanced, dtype=np.bool_), dt.shape).copy()
    h = 1.0
    bottom = np.zeros((dt.size, 4))
    if absorbing:
        for k, a0 in enumerate(a_bottom):
            q00, q01, row0 = absorbing_bottom(h, float(a0))
            bottom[k] = (q00, q01, row0[0], row0[1])
    y = np.ascontiguousarray(M, dtype=float)
    out, multipliers, n_exp, n_newton, info, stage = staged_run(
        h, *(np.ascontiguousarray(v) for v in (a, a1, a2, bf, bf1, bf2, bw, bw1, bw2)), bottom, dt, flags, y,
        np.ascontiguousarray(weights, dtype=float), float(p0), float(mean_tol), float(lin_tol), int(max_iter),
        res, theta, float(r_inf))
    if info != 0:
        why = "a pivot vanished" if info > 0 else "the balance did not converge"
        raise RuntimeError(f"run_stages: stage {stage} failed ({why}; info {info})")
    return out, multipliers, {"exponentials": int(n_exp), "newton_steps": int(n_newton)}
