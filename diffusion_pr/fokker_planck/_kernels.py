"""Numba kernels of the engine's staged integration (CRAM-16 and the balance substeps).

A staged problem (a closure: about a hundred shells, each one or more
exponentials, a balance multiplier per substep) makes hundreds of small
CRAM applications per grid; through LAPACK from Python each costs ~3x its
arithmetic in call overhead and copies.  These kernels do the same arithmetic
in one compiled call per grid:

* :func:`cram_pfd` -- ``exp(t L) y`` in partial fractions, a block of poles
  eliminated together row by row with LAPACK ``zgttrf``'s partial pivoting, in
  real arithmetic on split parts;
* :func:`gttrf` / :func:`gttrs` -- the complex tridiagonal LU with partial
  pivoting, row for row LAPACK's ``zgttrf`` / ``zgttrs``, keeping the reciprocal
  pivots so that a second solve with the same matrix (the derivative of
  :func:`cram_apply_d`) costs no division;
* :func:`cram_apply` -- ``exp(t L) y`` in the incomplete partial factorization
  form of :mod:`.cram` (same coefficients, same order of operations);
* :func:`balanced_stage` -- the balance substeps of
  :func:`~diffusion_pr.fokker_planck.engine.solve_on_grid`;
* :func:`staged_run` / :func:`staged_run_rows` -- every stage of one grid in one
  call (the bands of all stages as rows of 2-D arrays, or made stage by stage
  from the coefficient rows).

Plain ``numba.njit(cache=True)``, no fastmath (the results agree with the LAPACK
path to round-off; ``tests/diffusion_pr/test_fv_kernels.py``), numba's numpy error
model (IEEE division: no ZeroDivisionError branch per division).  Imported lazily
by the engine: a single-stage problem never loads numba.
"""
from __future__ import annotations

import math
import numpy as np
from numba import njit

from .expm import ALPHA, ALPHA0, PFD_RESIDUES, THETA

__all__ = ["cram_pfd", "gttrf", "gttrs", "cram_apply", "cram_apply_d", "balanced_stage", "staged_run",
           "staged_run_rows", "ALPHA", "THETA", "ALPHA0", "PFD_RESIDUES"]


@njit(cache=True, nogil=True, error_model="numpy")
def _cabs1(z):  # pragma: no cover - numba
    return abs(z.real) + abs(z.imag)


@njit(cache=True, nogil=True, error_model="numpy")
def _rec(z):  # pragma: no cover - numba
    """``1/z`` by one real division (``conj(z)/|z|^2``); numba's complex division where that could over/underflow."""
    x = z.real
    y = z.imag
    ax = abs(x)
    ay = abs(y)
    if ax < 1e150 and ay < 1e150 and (ax > 1e-150 or ay > 1e-150):
        s = 1.0 / (x * x + y * y)
        return complex(x * s, -y * s)
    return 1.0 / z


@njit(cache=True, nogil=True, error_model="numpy")
def cram_apply(lower, diag, upper, t, y, alpha, theta, alpha0):  # pragma: no cover - numba
    """``exp(t L) y`` (CRAM-16, IPF form) for the tridiagonal ``L``; returns ``(y_new, info)``."""
    out, _, info = _ipf(lower, diag, upper, lower, diag, upper, t, y, alpha, theta, alpha0, False)
    return out, info


@njit(cache=True, nogil=True, error_model="numpy")
def gttrf(dl, d, du, du2, ipiv):  # pragma: no cover - numba
    """LU factorization with partial pivoting of the tridiagonal ``(dl, d, du)``, in place; LAPACK ``zgttrf``.

    The pivoting of LAPACK ``zgttrf`` row for row; on return ``dl`` holds the
    multipliers, ``du``, ``du2`` the superdiagonals of ``U`` (``du2`` made by
    interchanges), ``ipiv[i]`` the row interchanged with row ``i`` (``i`` or
    ``i + 1``, 0-based) and ``d`` the *reciprocals* of ``U``'s diagonal (one
    division per row, shared by every solve of :func:`gttrs`).
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
    """``exp(t (L - A W)) y`` (CRAM-16, IPF form, as :func:`cram_apply`) and its derivative in ``A``.

    The bands ``(lower, diag, upper)`` are ``L - A W`` at the current ``A``. With
    ``M_j = t (L - A W) - theta_j`` the IPF step is ``x <- x + 2 Re(alpha_j M_j^-1 x)``;
    since ``dM_j/dA = -t W`` its derivative is
    ``dx <- dx + 2 Re(alpha_j M_j^-1 (dx + t W M_j^-1 x))``: one factorization
    (:func:`gttrf`) and two solves per pole, the exact derivative of the
    computed map.  Returns ``(x, dx, info)``.
    """
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
    """One operator's bands (:func:`.operator.bands`'s formula) into ``lower, diag, upper`` (overwritten).

    ``reached``: the wall is ``p = 0`` (a drift away from it carries back what diffusion takes out, at most:
    :func:`.operator.wall_drift`); else the domain's bottom, which absorbs.

    ``fitted``: the drift takes the upwinding weight of :func:`.operator.fitted_weight` (``f_row`` its
    diffusivity), as ``operator.bands(..., fitted=True)``; else the central value.
    """
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


#: poles per block of :func:`cram_pfd` (their eliminations interleave): all of CRAM-16's 8 poles in one block
#: while the block's arrays (about 4 per row and pole, 7 with the derivative) stay within this many, else blocks
#: of 4 or 2 (one block of 8 took 0.83-0.93x the time of two blocks of 4 on 300-2500 cells)
_PFD_BLOCK_WORDS = 250000
#: the largest block of poles (interleaved eliminations) of :func:`cram_pfd`
_PFD_MAX_BLOCK = 8


@njit(cache=True, nogil=True, error_model="numpy")
def cram_pfd(lower, diag, upper, wl, wd, wu, t, y, c, theta, alpha0, want_d):  # pragma: no cover - numba
    """``exp(t L) y`` by CRAM-16 in partial fractions, ``alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y``, and
    with ``want_d`` its derivative in ``A`` (:func:`_pfd_pivoting`).  Returns ``(x, dx, info)``.

    First without row interchanges (:func:`_pfd_dominant`, whose loops over the poles LLVM runs in vector
    registers); where any pole would interchange rows, or a pivot's reciprocal needs the guarded division, again
    with partial pivoting (:func:`_pfd_pivoting`).  Where no row is interchanged the two do the same operations
    in the same order: the same bits."""
    cw, r0 = flux_weights(c, theta, alpha0)
    if t != 0.0 and diag.size > 2:
        out, dout, done = _pfd_dominant(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d)
        if done:
            return out, dout, 0
    return _pfd_pivoting(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d)


#: poles per block of :func:`_pfd_dominant` (CRAM-16's 8; fewer poles leave lanes unused)
_LANES = 8
#: entries per row of :func:`_pfd_dominant`'s work array: ``_LANES`` each of the reciprocal pivot (real, imaginary
#: part), the right-hand side then solution (real, imaginary), and the derivative's (real, imaginary)
_ROW = 6 * _LANES


@njit(cache=True, nogil=True, error_model="numpy")
def _pfd_dominant(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d):  # pragma: no cover - numba
    """:func:`_pfd_pivoting` for matrices that need no row interchange, the poles side by side.

    The elimination of row ``i`` keeps the pivot row (``|d_i| >= |t l_i|`` in the 1-norm, LAPACK's test) for
    every pole: the superdiagonal stays ``t u_i`` (real) and the reciprocal pivot is ``conj(d)/|d|^2``.  Each
    row's values of a block of :data:`_LANES` poles lie next to each other in one flat array (row ``i`` at
    ``i _ROW``), so that the loops over the poles have no branch and fixed distances between their loads and
    stores: LLVM vectorizes them.  The tests are gathered over the poles without branching; at the first row
    where any fails (a row interchange, or a pivot outside ``1e-150 ... 1e150``) returns ``(x, dx, False)``, and
    :func:`cram_pfd` pivots.  The sums
    over the poles are taken during the back substitutions (the solutions are not stored for a later pass).
    """
    n = diag.size
    m = theta.size
    wk = np.empty(n * _ROW)
    thr = np.zeros(_LANES)
    thi = np.zeros(_LANES)
    cwr = np.zeros(_LANES)
    cwi = np.zeros(_LANES)
    cr = np.zeros(_LANES)
    ci = np.zeros(_LANES)
    out = np.empty(n)
    wv = np.zeros(n)  # 2 Re sum_j (c_j / theta_j) x_j: the result is r0 y + t L wv (:func:`_flux_form`)
    dout = np.zeros(n)
    for g0 in range(0, m, _LANES):
        gs = min(_LANES, m - g0)
        for jj in range(gs):
            thr[jj] = theta[g0 + jj].real
            thi[jj] = theta[g0 + jj].imag
            cwr[jj] = cw[g0 + jj].real
            cwi[jj] = cw[g0 + jj].imag
            cr[jj] = c[g0 + jj].real
            ci[jj] = c[g0 + jj].imag
        if _dom_forward(wk, thr, thi, lower, diag, upper, t, y, n, gs):
            return out, dout, False
        _dom_back(wk, upper, t, n, gs, cwr, cwi, wv, False)
        if want_d:
            _dom_q(wk, lower, wl, wd, wu, t, n, gs)
            _dom_back(wk, upper, t, n, gs, cr, ci, dout, True)
    _flux_form(lower, upper, t, y, wv, r0, out)
    return out, dout, True


@njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _dom_forward(wk, thr, thi, lower, diag, upper, t, y, n, gs):  # pragma: no cover - numba
    """The forward elimination of :func:`_pfd_dominant` (``gs`` poles): the reciprocal pivots and the eliminated
    right-hand side into ``wk`` (row ``i``'s pivot waits in its reciprocal's place).  Returns whether any pole
    needs a row interchange or the guarded division."""
    G = _LANES
    for jj in range(gs):
        wk[jj] = t * diag[0] - thr[jj]
        wk[G + jj] = -thi[jj]
        wk[2 * G + jj] = y[0]
        wk[3 * G + jj] = 0.0
    bad = False
    for i in range(n - 1):
        tl = t * lower[i]
        atl = abs(tl)
        tu = t * upper[i]
        tdn = t * diag[i + 1]
        yn = y[i + 1]
        o = i * _ROW
        for jj in range(gs):
            x = wk[o + jj]
            z = wk[o + G + jj]
            s2 = x * x + z * z
            bad |= not (abs(x) + abs(z) >= atl and 1e-290 < s2 < 1e290)
            q = 1.0 / s2
            sr = x * q
            si = -z * q
            f_r = tl * sr
            f_i = tl * si
            wk[o + jj] = sr
            wk[o + G + jj] = si
            b_r = wk[o + 2 * G + jj]
            b_i = wk[o + 3 * G + jj]
            wk[o + _ROW + 2 * G + jj] = yn - (f_r * b_r - f_i * b_i)
            wk[o + _ROW + 3 * G + jj] = -(f_r * b_i + f_i * b_r)
            wk[o + _ROW + jj] = (tdn - thr[jj]) - f_r * tu
            wk[o + _ROW + G + jj] = -thi[jj] - f_i * tu
        if bad:  # pivoting from the start: no more work here
            return True
    o = (n - 1) * _ROW
    for jj in range(gs):  # the last pivot: :func:`_rec`'s first branch
        x = wk[o + jj]
        z = wk[o + G + jj]
        ax = abs(x)
        az = abs(z)
        bad |= not (ax < 1e150 and az < 1e150 and (ax > 1e-150 or az > 1e-150))
        s = 1.0 / (x * x + z * z)
        wk[o + jj] = x * s
        wk[o + G + jj] = -z * s
    return bad


@njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _dom_back(wk, upper, t, n, gs, cr, ci, acc, deriv):  # pragma: no cover - numba
    """Back substitution of :func:`_pfd_dominant`, ``x_i = (b_i - t u_i x_{i+1}) / d_i``, in place on the
    right-hand sides (``deriv``: the derivative's), and ``acc_i += 2 Re sum_j (cr_j + i ci_j) x_ij``."""
    for k in range(n):
        i = max(n - 1 - k, 0)  # (max: an index LLVM knows is not negative, no wraparound test per element)
        tu = t * upper[i] if i < n - 1 else 0.0
        if deriv:
            acc[i] += _dom_back_row(wk, i * _ROW + 4 * _LANES, i * _ROW, tu, gs, cr, ci, i < n - 1)
        else:
            acc[i] += _dom_back_row(wk, i * _ROW + 2 * _LANES, i * _ROW, tu, gs, cr, ci, i < n - 1)


@njit(cache=True, nogil=True, error_model="numpy", boundscheck=False, inline="always")
def _dom_back_row(wk, ob, o, tu, gs, cr, ci, inner):  # pragma: no cover - numba
    """Row ``i`` of :func:`_dom_back` (``ob``: where its right-hand sides start, ``o``: its reciprocal pivots;
    ``inner``: not the last row); returns ``2 Re sum_j c_j x_ij``."""
    G = _LANES
    if inner:
        for jj in range(gs):
            a = wk[ob + jj] - tu * wk[ob + _ROW + jj]
            b = wk[ob + G + jj] - tu * wk[ob + _ROW + G + jj]
            wk[ob + jj] = a * wk[o + jj] - b * wk[o + G + jj]
            wk[ob + G + jj] = a * wk[o + G + jj] + b * wk[o + jj]
    else:
        for jj in range(gs):
            a = wk[ob + jj]
            b = wk[ob + G + jj]
            wk[ob + jj] = a * wk[o + jj] - b * wk[o + G + jj]
            wk[ob + G + jj] = a * wk[o + G + jj] + b * wk[o + jj]
    s = 0.0
    for jj in range(gs):
        s += cr[jj] * wk[ob + jj] - ci[jj] * wk[ob + G + jj]
    return 2.0 * s


@njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _dom_q(wk, lower, wl, wd, wu, t, n, gs):  # pragma: no cover - numba
    """The derivative's right-hand side ``q = t W x`` of :func:`_pfd_dominant`, eliminated row by row with the
    multipliers ``t l_i / d_i`` (from the stored reciprocal pivots), into its place in ``wk``."""
    G = _LANES
    X = 2 * G  # the solutions
    Q = 4 * G
    for jj in range(gs):
        wk[Q + jj] = t * (wd[0] * wk[X + jj] + wu[0] * wk[_ROW + X + jj])
        wk[Q + G + jj] = t * (wd[0] * wk[X + G + jj] + wu[0] * wk[_ROW + X + G + jj])
    for i in range(n - 1):
        tl = t * lower[i]
        wli = wl[i]
        wdn = wd[i + 1]
        wun = wu[i + 1] if i < n - 2 else 0.0
        o = i * _ROW
        if i < n - 2:
            for jj in range(gs):
                raw_r = (wli * wk[o + X + jj] + wdn * wk[o + _ROW + X + jj] + wun * wk[o + 2 * _ROW + X + jj]) * t
                raw_i = (wli * wk[o + X + G + jj] + wdn * wk[o + _ROW + X + G + jj]
                         + wun * wk[o + 2 * _ROW + X + G + jj]) * t
                f_r = tl * wk[o + jj]
                f_i = tl * wk[o + G + jj]
                q_r = wk[o + Q + jj]
                q_i = wk[o + Q + G + jj]
                wk[o + _ROW + Q + jj] = raw_r - (f_r * q_r - f_i * q_i)
                wk[o + _ROW + Q + G + jj] = raw_i - (f_r * q_i + f_i * q_r)
        else:  # the last row: no superdiagonal term
            for jj in range(gs):
                raw_r = (wli * wk[o + X + jj] + wdn * wk[o + _ROW + X + jj]) * t
                raw_i = (wli * wk[o + X + G + jj] + wdn * wk[o + _ROW + X + G + jj]) * t
                f_r = tl * wk[o + jj]
                f_i = tl * wk[o + G + jj]
                q_r = wk[o + Q + jj]
                q_i = wk[o + Q + G + jj]
                wk[o + _ROW + Q + jj] = raw_r - (f_r * q_r - f_i * q_i)
                wk[o + _ROW + Q + G + jj] = raw_i - (f_r * q_i + f_i * q_r)


@njit(cache=True, nogil=True, error_model="numpy")
def flux_weights(c, theta, alpha0):  # pragma: no cover - numba
    """``(c_j / theta_j, r(0))`` of the partial fractions ``r(z) = alpha0 + 2 Re sum_j c_j/(z - theta_j)``: the
    weights of :func:`_flux_form`'s ``w`` and the factor of its ``y``."""
    cw = c / theta
    r0 = alpha0
    for j in range(c.size):
        r0 -= 2.0 * cw[j].real
    return cw, r0


@njit(cache=True, nogil=True, error_model="numpy")
def _block_size(n, m, want_d):  # pragma: no cover - numba
    """Poles per block of :func:`_pfd_pivoting` (see :data:`_PFD_BLOCK_WORDS`)."""
    g_size = min(m, _PFD_MAX_BLOCK)
    while g_size > 2 and n * (7 if want_d else 4) * g_size > _PFD_BLOCK_WORDS:
        g_size = (g_size + 1) // 2
    return g_size


@njit(cache=True, nogil=True, error_model="numpy")
def _pfd_pivoting(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d):  # pragma: no cover - numba
    """``exp(t L) y`` by CRAM-16 in partial fractions, ``alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y``.

    The solves of different poles are independent: a block of poles is
    eliminated together, row by row (LAPACK ``zgttrf``'s pivoting per pole, the
    right-hand side eliminated in the same sweep), which turns the latency-bound
    recurrence of one solve into independent ones.  Real and imaginary parts are
    kept apart (the subdiagonal ``t l_i`` and, where no row was interchanged, the
    superdiagonal ``t u_i`` are real: half the products of complex arithmetic).
    ``kind[i]`` records per pole where a row was interchanged (2) or inherits the
    complex superdiagonal an interchange made (1); only those rows store their
    superdiagonals.  With ``want_d`` also the derivative in ``A`` of
    ``exp(t (L - A W)) y`` for the balance bands ``W``:
    ``2 Re sum_j c_j M_j^-1 (t W) M_j^-1 y`` (a second solve per pole with the
    stored elimination).  Returns ``(x, dx, info)``; ``info > 0`` a zero pivot.
    """
    n = diag.size
    m = theta.size
    g_size = _block_size(n, m, want_d)
    rr = np.empty((n, g_size))  # reciprocal pivots
    ri = np.empty((n, g_size))
    br = np.empty((n, g_size))  # right-hand side, then solution
    bi = np.empty((n, g_size))
    kind = np.zeros((n, g_size), dtype=np.int8)
    ur = np.empty((n, g_size))  # superdiagonals of U, read where kind != 0
    ui = np.empty((n, g_size))
    u2 = np.empty((n, g_size))
    nd = n if want_d else 1
    fr = np.empty((nd, g_size))  # multipliers
    fi = np.empty((nd, g_size))
    qr = np.empty((nd, g_size))  # t W x, then its solution
    qi = np.empty((nd, g_size))
    pr = np.empty(g_size)  # the current pivot
    pi = np.empty(g_size)
    cur_r = np.empty(g_size)  # the current row's superdiagonal where an interchange made it complex
    cur_i = np.empty(g_size)
    inherited = np.zeros(g_size, dtype=np.bool_)
    th_r = np.empty(g_size)
    th_i = np.empty(g_size)
    out = np.empty(n)
    wv = np.zeros(n)  # 2 Re sum_j (c_j / theta_j) x_j: the result is r0 y + t L wv (:func:`_flux_form`)
    dout = np.zeros(n)
    if t == 0.0:
        for i in range(n):
            out[i] = y[i]
        return out, dout, 0
    for g0 in range(0, m, g_size):
        gs = min(g_size, m - g0)  # the poles of this block
        if g0 > 0:
            kind[:, :] = 0
        for jj in range(gs):
            th_r[jj] = theta[g0 + jj].real
            th_i[jj] = theta[g0 + jj].imag
            pr[jj] = t * diag[0] - th_r[jj]
            pi[jj] = -th_i[jj]
            br[0, jj] = y[0]
            bi[0, jj] = 0.0
            inherited[jj] = False
        for i in range(n - 1):
            tl = t * lower[i]
            atl = abs(tl)
            tu = t * upper[i]
            tdn = t * diag[i + 1]
            tun = t * upper[i + 1] if i < n - 2 else 0.0
            yn = y[i + 1]
            for jj in range(gs):
                x = pr[jj]
                z = pi[jj]
                if abs(x) + abs(z) >= atl:  # row i stays the pivot row (LAPACK's test)
                    s2 = x * x + z * z
                    if 1e-290 < s2 < 1e290:
                        q = 1.0 / s2
                        sr = x * q
                        si = -z * q
                    else:
                        if x == 0.0 and z == 0.0:
                            return out, dout, i + 1
                        w = 1.0 / complex(x, z)
                        sr = w.real
                        si = w.imag
                    f_r = tl * sr
                    f_i = tl * si
                    rr[i, jj] = sr
                    ri[i, jj] = si
                    b_r = br[i, jj]
                    b_i = bi[i, jj]
                    br[i + 1, jj] = yn - (f_r * b_r - f_i * b_i)
                    bi[i + 1, jj] = -(f_r * b_i + f_i * b_r)
                    if inherited[jj]:  # the complex superdiagonal of an interchange above
                        ucr = cur_r[jj]
                        uci = cur_i[jj]
                        pr[jj] = (tdn - th_r[jj]) - (f_r * ucr - f_i * uci)
                        pi[jj] = -th_i[jj] - (f_r * uci + f_i * ucr)
                        kind[i, jj] = 1
                        ur[i, jj] = ucr
                        ui[i, jj] = uci
                        u2[i, jj] = 0.0
                        inherited[jj] = False
                    else:
                        pr[jj] = (tdn - th_r[jj]) - f_r * tu
                        pi[jj] = -th_i[jj] - f_i * tu
                else:  # rows i and i + 1 interchanged
                    ucr = cur_r[jj] if inherited[jj] else tu
                    uci = cur_i[jj] if inherited[jj] else 0.0
                    s = 1.0 / tl
                    f_r = x * s
                    f_i = z * s
                    dnr = tdn - th_r[jj]
                    dni = -th_i[jj]
                    kind[i, jj] = 2
                    ur[i, jj] = dnr
                    ui[i, jj] = dni
                    u2[i, jj] = tun
                    pr[jj] = ucr - (f_r * dnr - f_i * dni)
                    pi[jj] = uci - (f_r * dni + f_i * dnr)
                    cur_r[jj] = -f_r * tun
                    cur_i[jj] = -f_i * tun
                    inherited[jj] = True
                    rr[i, jj] = s
                    ri[i, jj] = 0.0
                    b_r = br[i, jj]
                    b_i = bi[i, jj]
                    br[i, jj] = yn
                    bi[i, jj] = 0.0
                    br[i + 1, jj] = b_r - f_r * yn
                    bi[i + 1, jj] = b_i - f_i * yn
                if want_d:
                    fr[i, jj] = f_r
                    fi[i, jj] = f_i
        for jj in range(gs):
            x = pr[jj]
            z = pi[jj]
            if x == 0.0 and z == 0.0:
                return out, dout, n
            w = _rec(complex(x, z))
            rr[n - 1, jj] = w.real
            ri[n - 1, jj] = w.imag
        _back(rr, ri, kind, ur, ui, u2, upper, t, br, bi, n, gs)
        _accumulate(wv, cw, g0, br, bi, n, gs)
        if not want_d:
            continue
        # q = t W x row by row, eliminated in the same sweep with the stored multipliers and interchanges
        for jj in range(gs):
            qr[0, jj] = t * (wd[0] * br[0, jj] + (wu[0] * br[1, jj] if n > 1 else 0.0))
            qi[0, jj] = t * (wd[0] * bi[0, jj] + (wu[0] * bi[1, jj] if n > 1 else 0.0))
        for i in range(n - 1):
            last = i + 2 >= n
            for jj in range(gs):
                raw_r = wl[i] * br[i, jj] + wd[i + 1] * br[i + 1, jj]
                raw_i = wl[i] * bi[i, jj] + wd[i + 1] * bi[i + 1, jj]
                if not last:
                    raw_r += wu[i + 1] * br[i + 2, jj]
                    raw_i += wu[i + 1] * bi[i + 2, jj]
                raw_r *= t
                raw_i *= t
                f_r = fr[i, jj]
                f_i = fi[i, jj]
                q_r = qr[i, jj]
                q_i = qi[i, jj]
                if kind[i, jj] == 2:
                    qr[i, jj] = raw_r
                    qi[i, jj] = raw_i
                    qr[i + 1, jj] = q_r - (f_r * raw_r - f_i * raw_i)
                    qi[i + 1, jj] = q_i - (f_r * raw_i + f_i * raw_r)
                else:
                    qr[i + 1, jj] = raw_r - (f_r * q_r - f_i * q_i)
                    qi[i + 1, jj] = raw_i - (f_r * q_i + f_i * q_r)
        _back(rr, ri, kind, ur, ui, u2, upper, t, qr, qi, n, gs)
        _accumulate(dout, c, g0, qr, qi, n, gs)
    _flux_form(lower, upper, t, y, wv, r0, out)
    return out, dout, 0


@njit(cache=True, nogil=True, error_model="numpy")
def _flux_form(lower, upper, t, y, w, r0, out):  # pragma: no cover - numba
    """``out = r0 y + t L w`` with ``t L w`` as differences of face fluxes: probability conserved to round-off.

    The partial fractions ``alpha0 y + 2 Re sum_j c_j x_j`` (``x_j = (t L - theta_j)^-1 y``) equal
    ``r(0) y + t L w`` with ``w = 2 Re sum_j (c_j/theta_j) x_j``, since
    ``(t L - theta)^-1 = (t L (t L - theta)^-1 - 1)/theta``.  ``L`` conserves probability (its
    column sums vanish: :func:`~diffusion_pr.fokker_planck.operator.bands`), so ``t L w`` is written
    with the net flux ``F_i = t (lower_i w_i - upper_i w_{i+1})`` from state ``i`` to ``i + 1``
    (the diagonal is not read): ``(t L w)_i = F_{i-1} - F_i`` telescopes, and the total is
    ``r(0) sum y`` up to ``eps sum |F|``.  The partial-fraction sum itself loses
    ``eps sum_i |t L_ii| m_i``: in stiff cells that hold probability (a drift trapping it far below
    the floor, ``|t L_ii|`` up to 1e8) that was 1e-6 of the mass over a solve (docs/backends.md,
    "Probability conserved in stiff cells").  ``out`` may be ``y`` (the IPF form updates in place).
    """
    n = y.size
    prev = 0.0
    for i in range(n - 1):
        flux = t * (lower[i] * w[i] - upper[i] * w[i + 1])
        out[i] = r0 * y[i] + (prev - flux)
        prev = flux
    out[n - 1] = r0 * y[n - 1] + prev


@njit(cache=True, nogil=True, error_model="numpy")
def _accumulate(out, c, g0, xr, xi, n, g_size):  # pragma: no cover - numba
    """``out += 2 Re sum_j c_j x_j`` over the block of poles starting at ``g0`` (``x = xr + i xi``)."""
    for i in range(n):
        s = 0.0
        for jj in range(g_size):
            cj = c[g0 + jj]
            s += cj.real * xr[i, jj] - cj.imag * xi[i, jj]
        out[i] += 2.0 * s


@njit(cache=True, nogil=True, error_model="numpy")
def _back(rr, ri, kind, ur, ui, u2, upper, t, br, bi, n, g_size):  # pragma: no cover - numba
    """Back substitution of :func:`_pfd_pivoting` for a block of poles, in place:
    ``x_i = (b_i - u_i x_{i+1} - u2_i x_{i+2}) / d_i`` (``rr + i ri`` the reciprocal pivots; ``u_i = t upper_i``
    and ``u2_i = 0`` where ``kind`` is 0)."""
    for jj in range(g_size):
        a = br[n - 1, jj]
        b = bi[n - 1, jj]
        br[n - 1, jj] = a * rr[n - 1, jj] - b * ri[n - 1, jj]
        bi[n - 1, jj] = a * ri[n - 1, jj] + b * rr[n - 1, jj]
    for i in range(n - 2, -1, -1):
        tu = t * upper[i]
        for jj in range(g_size):
            xr = br[i + 1, jj]
            xi = bi[i + 1, jj]
            if kind[i, jj] == 0:
                a = br[i, jj] - tu * xr
                b = bi[i, jj] - tu * xi
            else:
                a = br[i, jj] - (ur[i, jj] * xr - ui[i, jj] * xi)
                b = bi[i, jj] - (ur[i, jj] * xi + ui[i, jj] * xr)
                if i + 2 < n:
                    a -= u2[i, jj] * br[i + 2, jj]
                    b -= u2[i, jj] * bi[i + 2, jj]
            br[i, jj] = a * rr[i, jj] - b * ri[i, jj]
            bi[i, jj] = a * ri[i, jj] + b * rr[i, jj]


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
    """One CRAM application, partial fractions (``pfd``) or IPF, with its ``A``-derivative if ``want_d``."""
    if pfd:
        return cram_pfd(lo, di, up, wl, wd, wu, t, y, c, theta, alpha0, want_d)
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


#: entries of the predictor state carried from substep to substep (:func:`balanced_stage`): the number of
#: stored ratios, the last three ratios (newest first), the ratio of the mean's slope in ``A`` to its
#: linearization ``-dt <c, Lw u>``, and the fourth-last ratio
PREDICTOR_SIZE = 6
#: a substep's ratio ``A / A_midpoint`` outside (1/RATIO_RANGE, RATIO_RANGE) restarts the ratio history
RATIO_RANGE = 4.0
#: a predicted ``A`` whose mean misses ``p0`` by more than BAD_PREDICTION ``p0`` is not a start for Newton: the
#: start state's own balance ``A0`` is tried too (the explicit midpoint can be meaningless on a substep much
#: wider than the distribution, e.g. the first shell of a steep spectrum at ``p0`` far below its spread)
BAD_PREDICTION = 0.5


@njit(cache=True, nogil=True, error_model="numpy")
def _predicted_ratio(hist):  # pragma: no cover - numba
    """The next ratio ``A / A_midpoint``: the last four extrapolated by a cubic (fewer: a parabola, a line, a
    constant); on the Fig. 1 closures the cubic misses the root 5-60x less than a parabola."""
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
    """``m`` balance substeps of length ``dt`` on ``dy/dtau = (L0 - A Lw) y``, one ``A`` per substep.

    Per substep, ``A`` is predicted and tried with one plain CRAM application:

    * ``A_mid`` from ``<c, (L0 - A Lw) u> = 0`` at the midpoint state
      ``u = y + dt/2 (L0 - A0 Lw) y`` (``A0`` the same condition at ``y``), times
      the ratio ``A/A_mid`` of the last four substeps extrapolated by a cubic
      (it varies smoothly from shell to shell), minus ``(<c, y> - p0)/s``: the
      start's own miss of the mean, removed with the slope ``s = d<c, y_end>/dA``
      predicted as its linearization ``-dt <c, Lw u>`` times their ratio at the last
      substep where the slope was measured (the ratio varies slowly; the slope
      itself changed 5x over the shells at zeta = 4, and a stale slope made the
      ratio history oscillate and grow).
    * Where the mean then misses ``p0`` by more than ``mean_tol p0`` but less than
      ``lin_tol p0``: one secant step on ``A`` with the carried slope (a second
      plain application; its two points measure the slope afresh).
    * Where it still misses (or no slope is known yet): Newton on ``A`` with the
      exact derivative of the CRAM map (:func:`cram_apply_d`; regula falsi where
      a step leaves the bracket of the root); once the miss is below
      ``lin_tol p0`` the last step is taken on the state to first order,
      ``y <- y + dA dy/dA`` (mean exact, state error ``O(dA^2)``, about
      ``(lin_tol)^2``) instead of another application.

    * A prediction that misses by more than ``BAD_PREDICTION p0`` (the explicit
      midpoint is meaningless on a substep much wider than the distribution: the
      first shell of a steep spectrum at ``p0`` far below its spread) is compared
      with the start state's balance ``A0``, and the search goes on from the better
      one.  Wherever the miss is that large (at the start or after a step): Newton
      on ``ln(<p>/p0)`` (far from the root the computed mean saturates, at 0 and at
      the top of the domain, and Newton on the mean jumps from one saturation into
      the other), steps at most ``max(|A|, |A0|, 1)``, and bisection where a step
      leaves the bracket.

    Every substep ends with the mean within ``mean_tol p0`` of ``p0``; how it got
    there (prediction, secant, Newton) changes the state only within that
    tolerance.  ``hist`` (:data:`PREDICTOR_SIZE` floats, zeros at the start) is
    the predictor state, updated in place and carried over substeps and stages.

    Returns ``(y, n_cram, n_newton, info, residual)``: ``info`` 0, or ``> 0`` a
    singular shifted system, or ``-1`` the mean still missing after ``max_iter``
    corrections (``residual`` the relative miss; ``y`` not advanced past that
    substep).  ``n_newton`` counts the corrections (secant and Newton steps).
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
                if abs(err) > BAD_PREDICTION * p0:
                    # far from the root: Newton on ln(<p>/p0) (the computed mean saturates there, at 0 where the
                    # inward drift wins and at the top of the domain where the outward one does, and Newton on the
                    # mean jumps from one saturation into the other), steps of at most max(|A|, |A0|, 1), and
                    # bisection where a step leaves the bracket (regula falsi between two saturated ends creeps
                    # from one of them: 26 steps in a stress scene)
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
    """All stages of one grid in one call: row ``k`` of the band arrays is stage ``k``'s operator.

    Stage ``k`` applies ``reps[k]`` steps of length ``dt[k]``: plain exponentials
    ``exp(dt L_k)``, or (``balanced[k]``) balance substeps of :func:`balanced_stage`
    with the balance operator in row ``k`` of ``wl, wd, wu``.

    Returns ``(y, n_cram, n_newton, info, stage, residual)``; on ``info != 0``
    ``stage`` is the failing stage and ``y`` the state before it.
    """
    empty = np.zeros((1, 1))
    # bands given: no drift weight is chosen here (the ``fitted`` argument, ``balanced`` in its place, is not read)
    return _run(lower, diag, upper, wl, wd, wu, empty[0], empty, empty, empty, False, balanced, balanced, dt, reps,
                cvec, y, p0, mean_tol, lin_tol, max_iter, pfd, alpha, theta, alpha0, c)


@njit(cache=True, nogil=True, error_model="numpy")
def staged_run_rows(edges, f_rows, b_rows, w_rows, any_b, balanced, fitted, dt, reps, cvec, y, p0, mean_tol,
                    lin_tol, max_iter, pfd, alpha, theta, alpha0, c):  # pragma: no cover - numba
    """:func:`staged_run` for the native operator, its bands made stage by stage from the coefficient rows.

    ``f_rows`` (centres), ``b_rows`` and ``w_rows`` (faces) hold every stage's
    diffusivity, drift and balance; no band array of all stages is formed.
    ``fitted[k]``: stage ``k``'s drift takes its upwinding weight (:func:`_fill_row`).
    """
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
