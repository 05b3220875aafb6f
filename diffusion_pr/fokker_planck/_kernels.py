"""Numba kernels of the engine's staged integration: every stage of one grid in one compiled call.

A closure makes hundreds of small CRAM applications per grid (about a hundred shells, a balance multiplier per
substep); through LAPACK from Python each costs about 3x its arithmetic in call overhead.  Here: CRAM-16 in
partial fractions (:func:`~._pfd.cram_pfd`) or in the IPF form (:func:`cram_apply`: below ``PFD_MIN_RTOL``, and
where the partial fractions' elimination would interchange rows) on LAPACK's tridiagonal LU (:func:`gttrf` / :func:`gttrs`), the balance substeps (:func:`balanced_stage`) and the
stage loop (:func:`staged_run` / :func:`staged_run_rows`).  Plain ``njit(cache=True)``, no fastmath, numba's
numpy error model; the results agree with the LAPACK path to round-off (``tests/diffusion_pr/test_fv_kernels.py``).
"""
from __future__ import annotations

import math
import numpy as np
from numba import njit

from ._pfd import _flux_form, _cabs1, _rec, cram_pfd
from .expm import ALPHA, ALPHA0, PFD_RESIDUES, THETA

__all__ = ["cram_pfd", "gttrf", "gttrs", "cram_apply", "cram_apply_d", "balanced_stage", "staged_run",
           "staged_run_rows", "ALPHA", "THETA", "ALPHA0", "PFD_RESIDUES"]


@njit(cache=True, nogil=True, error_model="numpy")
def cram_apply(lower, diag, upper, t, y, alpha, theta, alpha0):  # pragma: no cover - numba
    """``exp(t L) y`` (CRAM-16, IPF form) for the tridiagonal ``L``; returns ``(y_new, info)``."""
    out, _, info = _ipf(lower, diag, upper, lower, diag, upper, t, y, alpha, theta, alpha0, False)
    return out, info


@njit(cache=True, nogil=True, error_model="numpy")
def gttrf(dl, d, du, du2, ipiv):  # pragma: no cover - numba
    """LU factorization of the tridiagonal ``(dl, d, du)`` in place, LAPACK ``zgttrf``'s pivoting row for row.

    On return ``dl`` holds the multipliers, ``du``, ``du2`` the superdiagonals of ``U``, ``ipiv[i]`` the row
    interchanged with row ``i`` and ``d`` the *reciprocals* of ``U``'s diagonal (shared by every :func:`gttrs`).
    Returns ``info``: 0, or the 1-based index of a zero pivot.
    """
    n = d.size
    for i in range(n):
        ipiv[i] = i
    for i in range(n - 2):
        du2[i] = 0.0
    for i in range(n - 1):
        if _cabs1(d[i]) >= _cabs1(dl[i]):
            if d[i] == 0.0:
                return i + 1
            r = _rec(d[i])
            fact = dl[i] * r
            dl[i] = fact
            d[i + 1] = d[i + 1] - fact * du[i]
            d[i] = r
        else:
            r = _rec(dl[i])
            fact = d[i] * r
            dl[i] = fact
            temp = du[i]
            du[i] = d[i + 1]
            d[i + 1] = temp - fact * d[i + 1]
            if i < n - 2:
                du2[i] = du[i + 1]
                du[i + 1] = -fact * du[i + 1]
            ipiv[i] = i + 1
            d[i] = r
    if d[n - 1] == 0.0:
        return n
    d[n - 1] = _rec(d[n - 1])
    return 0


@njit(cache=True, nogil=True, error_model="numpy")
def gttrs(dl, d, du, du2, ipiv, b):  # pragma: no cover - numba
    """Solve with the factors of :func:`gttrf`, ``b <- A^-1 b`` in place; LAPACK ``zgttrs`` (no transpose)."""
    n = d.size
    for i in range(n - 1):
        if ipiv[i] == i:
            b[i + 1] = b[i + 1] - dl[i] * b[i]
        else:
            temp = b[i]
            b[i] = b[i + 1]
            b[i + 1] = temp - dl[i] * b[i]
    b[n - 1] = b[n - 1] * d[n - 1]
    if n > 1:
        b[n - 2] = (b[n - 2] - du[n - 2] * b[n - 1]) * d[n - 2]
    for i in range(n - 3, -1, -1):
        b[i] = (b[i] - du[i] * b[i + 1] - du2[i] * b[i + 2]) * d[i]


@njit(cache=True, nogil=True, error_model="numpy")
def cram_apply_d(lower, diag, upper, wl, wd, wu, t, y, alpha, theta, alpha0):  # pragma: no cover - numba
    """``exp(t (L - A W)) y`` (IPF form, the bands given at the current ``A``) and its exact derivative in ``A``:
    with ``M_j = t (L - A W) - theta_j``, ``dx <- dx + 2 Re(alpha_j M_j^-1 (dx + t W M_j^-1 x))``, one factorization
    and two solves per pole.  Returns ``(x, dx, info)``."""
    return _ipf(lower, diag, upper, wl, wd, wu, t, y, alpha, theta, alpha0, True)


@njit(cache=True, nogil=True, error_model="numpy")
def _ipf(lower, diag, upper, wl, wd, wu, t, y, alpha, theta, alpha0, want_d):  # pragma: no cover - numba
    """CRAM-16 in IPF form, with the ``A``-derivative of :func:`cram_apply_d` if ``want_d``; each factor in flux
    form (``L`` must conserve probability, as every operator of the engine does)."""
    n = diag.size
    out = y.copy()
    dout = np.zeros(n)
    if t == 0.0:
        return out, dout, 0
    dl = np.empty(n - 1, dtype=np.complex128)
    du = np.empty(n - 1, dtype=np.complex128)
    du2 = np.empty(max(n - 2, 1), dtype=np.complex128)
    d = np.empty(n, dtype=np.complex128)
    ipiv = np.empty(n, dtype=np.int64)
    b = np.empty(n, dtype=np.complex128)
    r = np.empty(n, dtype=np.complex128)
    w = np.empty(n)
    for j in range(alpha.size):
        th = theta[j]
        for i in range(n - 1):
            dl[i] = t * lower[i]
            du[i] = t * upper[i]
        for i in range(n):
            d[i] = t * diag[i] - th
            b[i] = out[i]
        info = gttrf(dl, d, du, du2, ipiv)
        if info != 0:
            return out, dout, info
        gttrs(dl, d, du, du2, ipiv, b)
        a = alpha[j]
        if want_d:  # r = dx + t W b, solved with the same factors
            for i in range(n):
                r[i] = dout[i] + t * wd[i] * b[i]
            for i in range(n - 1):
                r[i + 1] += t * wl[i] * b[i]
                r[i] += t * wu[i] * b[i + 1]
            gttrs(dl, d, du, du2, ipiv, r)
            for i in range(n):
                dout[i] += 2.0 * (a * r[i]).real
        # out + 2 Re(a b) = (1 - 2 Re(a/th)) out + t L 2 Re(a b/th), in flux form (:func:`_flux_form`)
        aw = a / th
        for i in range(n):
            w[i] = 2.0 * (aw * b[i]).real
        _flux_form(lower, upper, t, out, w, 1.0 - 2.0 * aw.real, out)
    for i in range(n):
        out[i] *= alpha0
        dout[i] *= alpha0
    return out, dout, 0


@njit(cache=True, nogil=True, error_model="numpy")
def _geometry(edges):  # pragma: no cover - numba
    """Per-grid factors of the bands: ``(h, 1/(c_{i+1} - c_i), 1/(c_0 - p_wall), 1/(2h))``."""
    n = edges.size - 1
    h = np.empty(n)
    c = np.empty(n)
    for i in range(n):
        h[i] = edges[i + 1] - edges[i]
        c[i] = 0.5 * (edges[i + 1] + edges[i])
    k_int = np.empty(max(n - 1, 1))
    for i in range(n - 1):
        k_int[i] = 1.0 / (c[i + 1] - c[i])
    half_inv_h = np.empty(n)
    for i in range(n):
        half_inv_h[i] = 0.5 / h[i]
    return h, k_int, 1.0 / (c[0] - edges[0]), half_inv_h


@njit(cache=True, nogil=True, error_model="numpy")
def _fitted_weight(shift, f_min):  # pragma: no cover - numba
    """:func:`.operator.fitted_weight` of one face."""
    x = abs(shift)
    if x <= 2.0 * f_min:
        return 0.0
    out = 0.5 - f_min / x
    return out if shift > 0.0 else -out


@njit(cache=True, nogil=True, error_model="numpy")
def _fill_row(h, k_int, wall, half_inv_h, f_row, a_row, with_drift, with_diffusion, fitted, reached,
              lower, diag, upper):  # pragma: no cover - numba
    """One operator's bands, :func:`.operator.bands`'s formula, into ``lower, diag, upper`` (overwritten).
    ``reached``: the wall is ``p = 0`` (:func:`.operator.wall_drift`), else an absorbing bottom; ``fitted``: the
    drift takes :func:`.operator.fitted_weight`."""
    n = h.size
    for i in range(n):
        lower[i] = 0.0
        upper[i] = 0.0
    for i in range(n + 1):
        diag[i] = 0.0
    if with_diffusion:
        g_prev = f_row[0] / h[0]
        for i in range(n - 1):
            g_next = f_row[i + 1] / h[i + 1]
            left = k_int[i] * g_prev
            right = k_int[i] * g_next
            diag[i + 1] -= left
            upper[i + 1] += right
            diag[i + 2] -= right
            lower[i + 1] += left
            g_prev = g_next
        out = (f_row[0] / h[0]) * wall
        diag[1] -= out
        upper[0] += out
    else:
        out = 0.0
    if with_drift:
        for i in range(n - 1):
            ai = a_row[i + 1]
            s = _fitted_weight(ai / k_int[i], min(f_row[i], f_row[i + 1])) if fitted else 0.0
            if s == 0.0:  # the central value, bit for bit
                cl = ai * half_inv_h[i]
                cr = ai * half_inv_h[i + 1]
            else:
                cl = ai * (0.5 + s) / h[i]
                cr = ai * (0.5 - s) / h[i + 1]
            diag[i + 1] -= cl
            upper[i + 1] -= cr
            lower[i + 1] += cl
            diag[i + 2] += cr
        aw = min(a_row[0], 0.0)  # towards the wall: out
        diag[1] += aw / h[0]
        upper[0] -= aw / h[0]
        if reached:
            back = min(max(a_row[0], 0.0) / h[0], out)  # away: back what diffusion takes out, at most
            diag[1] += back
            upper[0] -= back


@njit(cache=True, nogil=True, error_model="numpy")
def _matvec(lower, diag, upper, y, out):  # pragma: no cover - numba
    n = diag.size
    for i in range(n):
        out[i] = diag[i] * y[i]
    for i in range(n - 1):
        out[i + 1] += lower[i] * y[i]
        out[i] += upper[i] * y[i + 1]


@njit(cache=True, nogil=True, error_model="numpy")
def _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up):  # pragma: no cover - numba
    """``(lo, di, up) <- L0 - A Lw``: the bands of the stage operator at the multiplier ``A``."""
    for i in range(diag.size - 1):
        lo[i] = lower[i] - A * wl[i]
        up[i] = upper[i] - A * wu[i]
    for i in range(diag.size):
        di[i] = diag[i] - A * wd[i]


@njit(cache=True, nogil=True, error_model="numpy")
def _dot(a, b):  # pragma: no cover - numba
    s = 0.0
    for i in range(a.size):
        s += a[i] * b[i]
    return s


@njit(cache=True, nogil=True, error_model="numpy")
def _expm(lo, di, up, wl, wd, wu, t, y, pfd, want_d, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """One CRAM application with its ``A``-derivative if ``want_d``: partial fractions (``pfd``) where their
    elimination needs no row interchange, else the IPF form (pivoting, round-off 1e-15 against 1e-13)."""
    if pfd:
        x, dx, done = cram_pfd(lo, di, up, wl, wd, wu, t, y, c, theta, alpha0, want_d)
        if done:
            return x, dx, 0
    if want_d:
        return cram_apply_d(lo, di, up, wl, wd, wu, t, y, alpha, theta, alpha0)
    x, info = cram_apply(lo, di, up, t, y, alpha, theta, alpha0)
    return x, x, info


@njit(cache=True, nogil=True, error_model="numpy")
def _expm_at(lower, diag, upper, wl, wd, wu, A, lo, di, up, dt, y, pfd, want_d, alpha, theta, alpha0,
             c):  # pragma: no cover - numba
    """``exp(dt (L0 - A Lw)) y`` (and its ``A``-derivative if ``want_d``), the shifted bands made in ``lo, di, up``."""
    _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up)
    return _expm(lo, di, up, wl, wd, wu, dt, y, pfd, want_d, alpha, theta, alpha0, c)


#: the predictor state of :func:`balanced_stage`: the number of stored ratios, the last three ratios ``A/A_mid``
#: (newest first), the ratio of the mean's slope in ``A`` to its linearization, and the fourth-last ratio
PREDICTOR_SIZE = 6
#: a ratio ``A / A_mid`` outside (1/RATIO_RANGE, RATIO_RANGE) restarts the ratio history
RATIO_RANGE = 4.0
#: a predicted ``A`` whose mean misses ``p0`` by more than BAD_PREDICTION ``p0``: the start state's own balance
#: ``A0`` is tried too (the explicit midpoint is meaningless on a substep much wider than the distribution)
BAD_PREDICTION = 0.5


@njit(cache=True, nogil=True, error_model="numpy")
def _predicted_ratio(hist):  # pragma: no cover - numba
    """The next ratio ``A / A_mid``: the last four extrapolated by a cubic (fewer: a parabola, a line, a constant)."""
    k = int(hist[0])
    if k >= 4:
        r = 4.0 * hist[1] - 6.0 * hist[2] + 4.0 * hist[3] - hist[5]
    elif k == 3:
        r = 3.0 * hist[1] - 3.0 * hist[2] + hist[3]
    elif k == 2:
        r = 2.0 * hist[1] - hist[2]
    elif k == 1:
        r = hist[1]
    else:
        return 1.0
    if not 1.0 / RATIO_RANGE < r < RATIO_RANGE:
        return hist[1]
    return r


@njit(cache=True, nogil=True, error_model="numpy")
def _push_ratio(hist, r):  # pragma: no cover - numba
    if not 1.0 / RATIO_RANGE < r < RATIO_RANGE:
        hist[0] = 0.0
        return
    hist[5] = hist[3]
    hist[3] = hist[2]
    hist[2] = hist[1]
    hist[1] = r
    hist[0] = min(hist[0] + 1.0, 4.0)


@njit(cache=True, nogil=True, error_model="numpy")
def balanced_stage(lower, diag, upper, wl, wd, wu, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter, hist,
                   pfd, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """``m`` balance substeps of length ``dt`` on ``dy/dtau = (L0 - A Lw) y``, one ``A`` per substep, each ending
    with the mean within ``mean_tol p0`` of ``p0``.

    ``A`` is predicted from the balance ``<c, (L0 - A Lw) u> = 0`` at the explicit midpoint ``u`` (``A_mid``) times
    the ratio ``A/A_mid`` of the last four substeps extrapolated by a cubic, less the start's own miss of the mean
    over the carried slope ``d<c, y_end>/dA``, and tried with one plain CRAM application.  A miss below
    ``lin_tol p0`` takes one secant step with the carried slope; larger misses take Newton steps with the exact
    derivative of the CRAM map (regula falsi where a step leaves the root's bracket), the last one to first order
    on the state (``y <- y + dA dy/dA``) once the miss is below ``lin_tol p0``.  Far from the root (a miss above
    :data:`BAD_PREDICTION` ``p0``, where the computed mean saturates at 0 or at the domain's top) the start
    state's balance ``A0`` is tried too, and Newton runs on ``ln(<p>/p0)`` with steps of at most
    ``max(|A|, |A0|, 1)`` and bisection.  ``hist`` (:data:`PREDICTOR_SIZE` floats) is the predictor state, carried
    over substeps and stages.

    Returns ``(y, n_cram, n_newton, info, residual)``: ``info`` 0, ``> 0`` a singular shifted system, or ``-1`` the
    mean still missing after ``max_iter`` corrections (``residual`` the relative miss, ``y`` not advanced past that
    substep); ``n_newton`` counts the secant and Newton steps.
    """
    n = diag.size
    l0y = np.empty(n)
    lwy = np.empty(n)
    u = np.empty(n)
    lo = np.empty(n - 1)
    di = np.empty(n)
    up = np.empty(n - 1)
    n_cram = 0
    n_newton = 0
    for _ in range(m):
        _matvec(lower, diag, upper, y, l0y)
        _matvec(wl, wd, wu, y, lwy)
        denom = _dot(cvec, lwy)
        A = _dot(cvec, l0y) / denom if denom != 0.0 else 0.0
        a_0 = A
        s_lin = 0.0  # the linearized slope d<c, y_end>/dA = -dt <c, Lw u>
        if denom != 0.0:
            for i in range(n):
                u[i] = y[i] + 0.5 * dt * (l0y[i] - A * lwy[i])
            _matvec(lower, diag, upper, u, l0y)
            _matvec(wl, wd, wu, u, lwy)
            den_u = _dot(cvec, lwy)
            if den_u != 0.0:
                A = _dot(cvec, l0y) / den_u
                s_lin = -dt * den_u
        a_mid = A
        s_pred = hist[4] * s_lin  # < 0 where known (the mean falls as A grows)
        corr = (_dot(cvec, y) - p0) / s_pred if s_pred < 0.0 else 0.0
        A = a_mid * _predicted_ratio(hist) - corr
        have_d = not s_pred < 0.0 and denom != 0.0  # no slope yet: measure it with the first application
        trial, dtrial, info = _expm_at(lower, diag, upper, wl, wd, wu, A, lo, di, up, dt, y, pfd, have_d, alpha,
                                       theta, alpha0, c)
        n_cram += 1
        if info != 0:
            return y, n_cram, n_newton, info, 0.0
        err = _dot(cvec, trial) - p0
        slope = _dot(cvec, dtrial) if have_d else s_pred
        # bracket of the root: the mean falls as A grows, so err > 0 below the root, < 0 above
        a_lo = a_hi = A
        e_lo = e_hi = err
        has_lo = err > 0.0
        has_hi = err < 0.0
        if abs(err) > BAD_PREDICTION * p0 and denom != 0.0 and a_0 != A:
            # a meaningless prediction: the start state's balance A0 too; the search goes on from the better one
            trial0, dtrial0, info = _expm_at(lower, diag, upper, wl, wd, wu, a_0, lo, di, up, dt, y, pfd, True, alpha,
                                             theta, alpha0, c)
            n_cram += 1
            if info != 0:
                return y, n_cram, n_newton, info, 0.0
            err0 = _dot(cvec, trial0) - p0
            if abs(err0) < abs(err):  # the prediction is dropped, from the bracket too (far from the root the
                # computed mean need not fall monotonically in A: a strong drift is not resolved by the grid)
                A, err, trial, dtrial, have_d = a_0, err0, trial0, dtrial0, True
                slope = _dot(cvec, dtrial)
                a_lo = a_hi = A
                e_lo = e_hi = err
                has_lo = err > 0.0
                has_hi = err < 0.0
        it = 0
        while abs(err) > mean_tol * p0 and denom != 0.0:
            if it >= max_iter:
                return y, n_cram, n_newton, -1, abs(err) / p0
            n_newton += 1
            secant = it == 0 and not have_d and abs(err) <= lin_tol * p0
            if secant:  # with the carried slope: a plain application, and the slope measured by the two points
                A_new = A - err / s_pred
            else:
                if not have_d:  # the derivative at the current A (the application is recomputed with it)
                    trial, dtrial, info = _expm_at(lower, diag, upper, wl, wd, wu, A, lo, di, up, dt, y, pfd, True,
                                                   alpha, theta, alpha0, c)
                    n_cram += 1
                    if info != 0:
                        return y, n_cram, n_newton, info, 0.0
                    have_d = True
                slope = _dot(cvec, dtrial)
                if abs(err) > BAD_PREDICTION * p0:  # far from the root: Newton on ln(<p>/p0), bounded, bisection
                    radius = max(abs(A), abs(a_0), 1.0)
                    if slope < 0.0 and err + p0 > 0.0:
                        step = -math.log((err + p0) / p0) * (err + p0) / slope
                    else:  # no positive mean or not the expected monotone response: away from this side
                        step = radius if err > 0.0 else -radius
                    A_new = A + min(radius, max(-radius, step))
                    if has_lo and has_hi and not (min(a_lo, a_hi) < A_new < max(a_lo, a_hi)):
                        A_new = 0.5 * (a_lo + a_hi)
                else:
                    if slope < 0.0:
                        dA = -err / slope
                        if abs(err) <= lin_tol * p0:  # close enough: the last step to first order on the state
                            for i in range(n):
                                trial[i] += dA * dtrial[i]
                            err = _dot(cvec, trial) - p0
                            A += dA
                            break
                        A_new = A + dA
                    else:  # not the expected monotone response: away from this side
                        A_new = A + (1.0 if err > 0.0 else -1.0) * (abs(A) + 1.0)
                    if has_lo and has_hi and not (min(a_lo, a_hi) < A_new < max(a_lo, a_hi)):
                        A_new = (a_lo * e_hi - a_hi * e_lo) / (e_hi - e_lo)  # outside the bracket: regula falsi
            trial, dtrial, info = _expm_at(lower, diag, upper, wl, wd, wu, A_new, lo, di, up, dt, y, pfd, not secant,
                                           alpha, theta, alpha0, c)
            n_cram += 1
            if info != 0:
                return y, n_cram, n_newton, info, 0.0
            err_new = _dot(cvec, trial) - p0
            if secant and A_new != A and (err_new - err) / (A_new - A) < 0.0:
                slope = (err_new - err) / (A_new - A)
            err = err_new
            if err > 0.0:
                a_lo, e_lo, has_lo = A_new, err, True
            elif err < 0.0:
                a_hi, e_hi, has_hi = A_new, err, True
            A = A_new
            it += 1
        if denom != 0.0 and slope < 0.0 and s_lin < 0.0:
            hist[4] = slope / s_lin
            if a_mid != 0.0:  # the ratio of the root (the accepted A less its remaining miss) to A_mid
                _push_ratio(hist, (A - err / slope + corr) / a_mid)
        y = trial
    return y, n_cram, n_newton, 0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def staged_run(lower, diag, upper, wl, wd, wu, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol, max_iter,
               pfd, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """All stages of one grid in one call, row ``k`` of the band arrays stage ``k``'s operator: ``reps[k]`` steps
    of ``dt[k]``, plain exponentials or (``balanced[k]``) :func:`balanced_stage` with the balance bands in row
    ``k`` of ``wl, wd, wu``.  Returns ``(y, n_cram, n_newton, info, stage, residual)``; on ``info != 0`` ``stage``
    is the failing stage and ``y`` the state before it.
    """
    empty = np.zeros((1, 1))  # (bands given: the ``fitted`` argument, ``balanced`` in its place, is not read)
    return _run(lower, diag, upper, wl, wd, wu, empty[0], empty, empty, empty, False, balanced, balanced, dt, reps,
                cvec, y, p0, mean_tol, lin_tol, max_iter, pfd, alpha, theta, alpha0, c)


@njit(cache=True, nogil=True, error_model="numpy")
def staged_run_rows(edges, f_rows, b_rows, w_rows, any_b, balanced, fitted, dt, reps, cvec, y, p0, mean_tol,
                    lin_tol, max_iter, pfd, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """:func:`staged_run` for the native operator, each stage's bands made from the rows ``f_rows`` (centres),
    ``b_rows`` and ``w_rows`` (faces); ``fitted[k]``: stage ``k``'s drift takes its upwinding weight."""
    empty = np.zeros((1, 1))
    return _run(empty, empty, empty, empty, empty, empty, edges, f_rows, b_rows, w_rows, any_b, balanced, fitted, dt,
                reps, cvec, y, p0, mean_tol, lin_tol, max_iter, pfd, alpha, theta, alpha0, c)


@njit(cache=True, nogil=True, error_model="numpy")
def _run(lower, diag, upper, wl, wd, wu, edges, f_rows, b_rows, w_rows, any_b, balanced, fitted, dt, reps, cvec, y,
         p0, mean_tol, lin_tol, max_iter, pfd, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """The stage loop of :func:`staged_run` (bands given) and :func:`staged_run_rows` (bands made per stage)."""
    from_rows = edges.size > 1
    n_stages = f_rows.shape[0] if from_rows else diag.shape[0]
    n = cvec.size
    lo = np.empty(n - 1)
    di = np.empty(n)
    up = np.empty(n - 1)
    wlo = np.empty(n - 1)
    wdi = np.empty(n)
    wup = np.empty(n - 1)
    reached = from_rows and edges[0] == 0.0
    if from_rows:
        h, k_int, wall, half_inv_h = _geometry(edges)
    else:
        h, k_int, wall, half_inv_h = np.empty(1), np.empty(1), 0.0, np.empty(1)
    n_cram = 0
    n_newton = 0
    hist = np.zeros(PREDICTOR_SIZE)
    for k in range(n_stages):
        if from_rows:
            _fill_row(h, k_int, wall, half_inv_h, f_rows[k], b_rows[k], any_b, True, fitted[k], reached, lo, di, up)
            if balanced[k]:
                _fill_row(h, k_int, wall, half_inv_h, f_rows[k], w_rows[k], True, False, False, reached, wlo, wdi,
                          wup)
        else:
            lo[:] = lower[k]
            di[:] = diag[k]
            up[:] = upper[k]
            if balanced[k]:
                wlo[:] = wl[k]
                wdi[:] = wd[k]
                wup[:] = wu[k]
        if balanced[k]:
            y_new, nc, nn, info, res = balanced_stage(
                lo, di, up, wlo, wdi, wup, cvec, y, dt[k], reps[k], p0, mean_tol, lin_tol,
                max_iter, hist, pfd, alpha, theta, alpha0, c)
            n_cram += nc
            n_newton += nn
            if info != 0:
                return y, n_cram, n_newton, info, k, res
            y = y_new
        else:
            for _ in range(reps[k]):
                y_new, _, info = _expm(lo, di, up, wlo, wdi, wup, dt[k], y, pfd, False, alpha, theta, alpha0, c)
                n_cram += 1
                if info != 0:
                    return y, n_cram, n_newton, info, k, 0.0
                y = y_new
    return y, n_cram, n_newton, 0, -1, 0.0
