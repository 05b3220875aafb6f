"""Numba kernels of the engine's staged integration (CRAM-16 and the balance substeps).

A staged problem (a closure: about a hundred shells, each one or more
exponentials, a balance multiplier per substep) makes hundreds of small
CRAM applications per grid; through LAPACK from Python each costs ~3x its
arithmetic in call overhead and copies.  These kernels do the same arithmetic
in one compiled call per grid:

* :func:`gtsv` -- the complex tridiagonal solve with partial pivoting, row for
  row LAPACK's ``zgtsv`` (Gaussian elimination with row interchanges; the
  interchange makes a second superdiagonal);
* :func:`cram_apply` -- ``exp(t L) y`` in the incomplete partial factorization
  form of :mod:`.cram` (same coefficients, same order of operations);
* :func:`balanced_stage` -- the balance substeps of
  :func:`~diffusion_pr.solvers.fv.engine.solve_on_grid`;
* :func:`staged_run` -- every stage of one grid in one call (the bands of all
  stages as rows of 2-D arrays).

Module-level ``numba.njit(cache=True)``, no fastmath (the results agree with the
LAPACK path to round-off; ``tests/diffusion_pr/test_fv_kernels.py``).  Imported
lazily by the engine: a single-stage problem never loads numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .cram import ALPHA, ALPHA0, THETA

__all__ = ["gtsv", "gttrf", "gttrs", "cram_apply", "cram_apply_d", "balanced_stage", "staged_run", "ALPHA", "THETA", "ALPHA0"]


@njit(cache=True)
def _cabs1(z):  # pragma: no cover - numba
    return abs(z.real) + abs(z.imag)


@njit(cache=True)
def gtsv(dl, d, du, b):  # pragma: no cover - numba
    """Solve the tridiagonal ``(dl, d, du) x = b`` in place (``b <- x``); LAPACK ``zgtsv``'s algorithm.

    ``dl``, ``d``, ``du`` are overwritten.  Returns ``info``: 0, or the
    (1-based) index of a zero pivot (the system is singular; ``b`` is then
    not a solution).
    """
    n = d.size
    for k in range(n - 1):
        if dl[k] == 0.0:
            if d[k] == 0.0:
                return k + 1
        elif _cabs1(d[k]) >= _cabs1(dl[k]):
            mult = dl[k] / d[k]
            d[k + 1] = d[k + 1] - mult * du[k]
            b[k + 1] = b[k + 1] - mult * b[k]
            if k < n - 2:
                dl[k] = 0.0
        else:
            mult = d[k] / dl[k]
            d[k] = dl[k]
            temp = d[k + 1]
            d[k + 1] = du[k] - mult * temp
            if k < n - 2:
                dl[k] = du[k + 1]
                du[k + 1] = -mult * dl[k]
            du[k] = temp
            temp = b[k]
            b[k] = b[k + 1]
            b[k + 1] = temp - mult * b[k + 1]
    if d[n - 1] == 0.0:
        return n
    b[n - 1] = b[n - 1] / d[n - 1]
    if n > 1:
        b[n - 2] = (b[n - 2] - du[n - 2] * b[n - 1]) / d[n - 2]
    for k in range(n - 3, -1, -1):
        b[k] = (b[k] - du[k] * b[k + 1] - dl[k] * b[k + 2]) / d[k]
    return 0


@njit(cache=True)
def cram_apply(lower, diag, upper, t, y, alpha, theta, alpha0):  # pragma: no cover - numba
    """``exp(t L) y`` (CRAM-16, IPF form) for the tridiagonal ``L``; returns ``(y_new, info)``."""
    n = diag.size
    out = y.copy()
    if t == 0.0:
        return out, 0
    dl = np.empty(n - 1, dtype=np.complex128)
    du = np.empty(n - 1, dtype=np.complex128)
    d = np.empty(n, dtype=np.complex128)
    b = np.empty(n, dtype=np.complex128)
    for j in range(alpha.size):
        for i in range(n - 1):
            dl[i] = t * lower[i]
            du[i] = t * upper[i]
        th = theta[j]
        for i in range(n):
            d[i] = t * diag[i] - th
            b[i] = out[i]
        info = gtsv(dl, d, du, b)
        if info != 0:
            return out, info
        a = alpha[j]
        for i in range(n):
            out[i] += 2.0 * (a * b[i]).real
    for i in range(n):
        out[i] *= alpha0
    return out, 0


@njit(cache=True)
def gttrf(dl, d, du, du2, ipiv):  # pragma: no cover - numba
    """LU factorization with partial pivoting of the tridiagonal ``(dl, d, du)``, in place; LAPACK ``zgttrf``.

    On return ``dl`` holds the multipliers, ``d``, ``du``, ``du2`` the rows of
    ``U`` (``du2`` the second superdiagonal made by interchanges) and
    ``ipiv[i]`` the row interchanged with row ``i`` (``i`` or ``i + 1``, 0-based).
    Returns ``info``: 0, or the 1-based index of a zero pivot.
    """
    n = d.size
    for i in range(n):
        ipiv[i] = i
    for i in range(n - 2):
        du2[i] = 0.0
    for i in range(n - 1):
        if _cabs1(d[i]) >= _cabs1(dl[i]):
            if d[i] != 0.0:
                fact = dl[i] / d[i]
                dl[i] = fact
                d[i + 1] = d[i + 1] - fact * du[i]
        else:
            fact = d[i] / dl[i]
            d[i] = dl[i]
            dl[i] = fact
            temp = du[i]
            du[i] = d[i + 1]
            d[i + 1] = temp - fact * d[i + 1]
            if i < n - 2:
                du2[i] = du[i + 1]
                du[i + 1] = -fact * du[i + 1]
            ipiv[i] = i + 1
    for i in range(n):
        if d[i] == 0.0:
            return i + 1
    return 0


@njit(cache=True)
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
    b[n - 1] = b[n - 1] / d[n - 1]
    if n > 1:
        b[n - 2] = (b[n - 2] - du[n - 2] * b[n - 1]) / d[n - 2]
    for i in range(n - 3, -1, -1):
        b[i] = (b[i] - du[i] * b[i + 1] - du2[i] * b[i + 2]) / d[i]


@njit(cache=True)
def cram_apply_d(lower, diag, upper, wl, wd, wu, t, y, alpha, theta, alpha0):  # pragma: no cover - numba
    """``exp(t (L - A W)) y`` (CRAM-16, IPF form, as :func:`cram_apply`) and its derivative in ``A``.

    The bands ``(lower, diag, upper)`` are ``L - A W`` at the current ``A``. With
    ``M_j = t (L - A W) - theta_j`` the IPF step is ``x <- x + 2 Re(alpha_j M_j^-1 x)``;
    since ``dM_j/dA = -t W`` its derivative is
    ``dx <- dx + 2 Re(alpha_j M_j^-1 (dx + t W M_j^-1 x))``: one factorization
    (:func:`gttrf`) and two solves per pole, the exact derivative of the
    computed map.  Returns ``(x, dx, info)``.
    """
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
        # r = dx + t W b
        for i in range(n):
            r[i] = dout[i] + t * wd[i] * b[i]
        for i in range(n - 1):
            r[i + 1] += t * wl[i] * b[i]
            r[i] += t * wu[i] * b[i + 1]
        gttrs(dl, d, du, du2, ipiv, r)
        a = alpha[j]
        for i in range(n):
            out[i] += 2.0 * (a * b[i]).real
            dout[i] += 2.0 * (a * r[i]).real
    for i in range(n):
        out[i] *= alpha0
        dout[i] *= alpha0
    return out, dout, 0


@njit(cache=True)
def _matvec(lower, diag, upper, y, out):  # pragma: no cover - numba
    n = diag.size
    for i in range(n):
        out[i] = diag[i] * y[i]
    for i in range(n - 1):
        out[i + 1] += lower[i] * y[i]
        out[i] += upper[i] * y[i + 1]


@njit(cache=True)
def _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up):  # pragma: no cover - numba
    """``(lo, di, up) <- L0 - A Lw``: the bands of the stage operator at the multiplier ``A``."""
    for i in range(diag.size - 1):
        lo[i] = lower[i] - A * wl[i]
        up[i] = upper[i] - A * wu[i]
    for i in range(diag.size):
        di[i] = diag[i] - A * wd[i]


@njit(cache=True)
def _dot(a, b):  # pragma: no cover - numba
    s = 0.0
    for i in range(a.size):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def balanced_stage(lower, diag, upper, wl, wd, wu, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter, use_d, ratio,
                   alpha, theta, alpha0):  # pragma: no cover - numba
    """``m`` balance substeps of length ``dt`` on ``dy/dtau = (L0 - A Lw) y``, one ``A`` per substep.

    Per substep: ``A`` predicted from ``<c, (L0 - A Lw) u> = 0`` at the midpoint
    state ``u = y + dt/2 (L0 - A0 Lw) y`` (``A0`` the same condition at ``y``) and
    one CRAM application.  While the mean misses ``p0`` by more than
    ``mean_tol p0``: Newton on ``A`` with the exact derivative of the CRAM map
    (:func:`cram_apply_d`; regula falsi where a step leaves the bracket of the
    root).  Once the miss is below ``lin_tol p0`` the last step is taken on the
    state to first order, ``y <- y + dA dy/dA`` (mean exact, state error
    ``O(dA^2)``, about ``(lin_tol)^2``) instead of another application.
    ``use_d`` (carried over substeps) computes the derivative with the first
    application where the previous substep needed a correction.

    Returns ``(y, n_cram, n_newton, info, residual, use_d)``: ``info`` 0, or ``> 0``
    a singular shifted system, or ``-1`` the mean still missing after
    ``max_iter`` steps (``residual`` the relative miss; ``y`` not advanced past
    that substep).
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
        if denom != 0.0:
            for i in range(n):
                u[i] = y[i] + 0.5 * dt * (l0y[i] - A * lwy[i])
            _matvec(lower, diag, upper, u, l0y)
            _matvec(wl, wd, wu, u, lwy)
            den_u = _dot(cvec, lwy)
            if den_u != 0.0:
                A = _dot(cvec, l0y) / den_u
        a_pred = A
        if use_d:  # the previous substep needed a correction: apply its ratio (smooth from shell to shell)
            A = a_pred * ratio
        _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up)
        if use_d:
            trial, dtrial, info = cram_apply_d(lo, di, up, wl, wd, wu, dt, y, alpha, theta, alpha0)
        else:
            trial, info = cram_apply(lo, di, up, dt, y, alpha, theta, alpha0)
            dtrial = l0y  # placeholder: no derivative yet
        have_d = use_d
        n_cram += 1
        if info != 0:
            return y, n_cram, n_newton, info, 0.0, use_d, ratio
        err = _dot(cvec, trial) - p0
        use_d = abs(err) > mean_tol * p0 and denom != 0.0
        # bracket of the root: the mean falls as A grows, so err > 0 below the root, < 0 above
        a_lo = a_hi = A
        e_lo = e_hi = err
        has_lo = err > 0.0
        has_hi = err < 0.0
        it = 0
        while abs(err) > mean_tol * p0 and denom != 0.0:
            if it >= max_iter:
                return y, n_cram, n_newton, -1, abs(err) / p0, use_d, ratio
            if not have_d:  # the derivative at the current A (the application is recomputed with it)
                _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up)
                trial, dtrial, info = cram_apply_d(lo, di, up, wl, wd, wu, dt, y, alpha, theta, alpha0)
                n_cram += 1
                if info != 0:
                    return y, n_cram, n_newton, info, 0.0, use_d, ratio
                have_d = True
            slope = _dot(cvec, dtrial)
            n_newton += 1
            if slope < 0.0:
                dA = -err / slope
                if abs(err) <= lin_tol * p0:  # close enough: the last step to first order on the state
                    for i in range(n):
                        trial[i] += dA * dtrial[i]
                    err = _dot(cvec, trial) - p0
                    A += dA
                    break
                A_new = A + dA
            else:  # not the expected monotone response: halve towards the other side
                A_new = A + (1.0 if err > 0.0 else -1.0) * (abs(A) + 1.0)
            if has_lo and has_hi and not (min(a_lo, a_hi) < A_new < max(a_lo, a_hi)):
                A_new = (a_lo * e_hi - a_hi * e_lo) / (e_hi - e_lo)  # outside the bracket: regula falsi
            _shifted(lower, diag, upper, wl, wd, wu, A_new, lo, di, up)
            trial, dtrial, info = cram_apply_d(lo, di, up, wl, wd, wu, dt, y, alpha, theta, alpha0)
            n_cram += 1
            if info != 0:
                return y, n_cram, n_newton, info, 0.0, use_d, ratio
            err = _dot(cvec, trial) - p0
            if err > 0.0:
                a_lo, e_lo, has_lo = A_new, err, True
            elif err < 0.0:
                a_hi, e_hi, has_hi = A_new, err, True
            A = A_new
            it += 1
        ratio = A / a_pred if (a_pred != 0.0 and 0.5 < A / a_pred < 2.0) else 1.0
        y = trial
    return y, n_cram, n_newton, 0, 0.0, use_d, ratio


@njit(cache=True)
def staged_run(lower, diag, upper, wl, wd, wu, balanced, dt, reps, cvec, y, p0, mean_tol, lin_tol, max_iter,
               alpha, theta, alpha0):  # pragma: no cover - numba
    """All stages of one grid in one call: row ``k`` of the band arrays is stage ``k``'s operator.

    Stage ``k`` applies ``reps[k]`` steps of length ``dt[k]``: plain exponentials
    ``exp(dt L_k)``, or (``balanced[k]``) balance substeps of :func:`balanced_stage`
    with the balance operator in row ``k`` of ``wl, wd, wu``.

    Returns ``(y, n_cram, n_newton, info, stage, residual)``; on ``info != 0``
    ``stage`` is the failing stage and ``y`` the state before it.
    """
    n_cram = 0
    n_newton = 0
    use_d = False
    ratio = 1.0
    for k in range(diag.shape[0]):
        if balanced[k]:
            y_new, nc, nn, info, res, use_d, ratio = balanced_stage(
                lower[k], diag[k], upper[k], wl[k], wd[k], wu[k], cvec, y, dt[k], reps[k], p0, mean_tol, lin_tol,
                max_iter, use_d, ratio, alpha, theta, alpha0)
            n_cram += nc
            n_newton += nn
            if info != 0:
                return y, n_cram, n_newton, info, k, res
            y = y_new
        else:
            for _ in range(reps[k]):
                y_new, info = cram_apply(lower[k], diag[k], upper[k], dt[k], y, alpha, theta, alpha0)
                n_cram += 1
                if info != 0:
                    return y, n_cram, n_newton, info, k, 0.0
                y = y_new
    return y, n_cram, n_newton, 0, -1, 0.0
