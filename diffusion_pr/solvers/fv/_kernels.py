"""Numba kernels of the engine's staged integration (CRAM-16 and the balance substeps).

A staged problem (a closure: about a hundred shells, each one or more
exponentials, a balance multiplier per substep) makes hundreds of small
CRAM applications per grid; through LAPACK from Python each costs ~3x its
arithmetic in call overhead and copies.  These kernels do the same arithmetic
in one compiled call per stage:

* :func:`gtsv` -- the complex tridiagonal solve with partial pivoting, row for
  row LAPACK's ``zgtsv`` (Gaussian elimination with row interchanges; the
  interchange makes a second superdiagonal);
* :func:`cram_apply` -- ``exp(t L) y`` in the incomplete partial factorization
  form of :mod:`.cram` (same coefficients, same order of operations);
* :func:`balanced_stage` -- the balance substeps of
  :func:`~diffusion_pr.solvers.fv.engine.solve_on_grid`.

Module-level ``numba.njit(cache=True)``, no fastmath (the results agree with the
LAPACK path to round-off; ``tests/diffusion_pr/test_fv_kernels.py``).  Imported
lazily by the engine: a single-stage problem never loads numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .cram import ALPHA, ALPHA0, THETA

__all__ = ["gtsv", "cram_apply", "balanced_stage", "ALPHA", "THETA", "ALPHA0"]


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
def balanced_stage(lower, diag, upper, wl, wd, wu, cvec, y, dt, m, p0, mean_tol,
                   alpha, theta, alpha0):  # pragma: no cover - numba
    """``m`` balance substeps of length ``dt`` on ``dy/dtau = (L0 - A Lw) y``; see ``solve_on_grid``.

    Per substep: ``A`` from ``<c, (L0 - A Lw) u> = 0`` at the midpoint state
    ``u = y + dt/2 (L0 - A0 Lw) y`` (``A0`` the same condition at ``y``), one
    CRAM application, and where the mean then misses ``p0`` by more than
    ``mean_tol p0`` one Newton step on ``A`` (a second application).

    Returns ``(y, n_cram, n_newton, info)``; ``info != 0`` is a singular shifted system.
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
        _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up)
        trial, info = cram_apply(lo, di, up, dt, y, alpha, theta, alpha0)
        n_cram += 1
        if info != 0:
            return y, n_cram, n_newton, info
        err = _dot(cvec, trial) - p0
        if abs(err) > mean_tol * p0 and denom != 0.0:
            A += err / (dt * denom)
            _shifted(lower, diag, upper, wl, wd, wu, A, lo, di, up)
            trial, info = cram_apply(lo, di, up, dt, y, alpha, theta, alpha0)
            n_cram += 1
            n_newton += 1
            if info != 0:
                return y, n_cram, n_newton, info
        y = trial
    return y, n_cram, n_newton, 0
