"""Numba kernels of CRAM-16 in partial fractions: ``exp(t L) y = alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y``,
all poles' shifted tridiagonal systems eliminated together without row interchanges (:func:`cram_pfd`), the sum
in flux form (:func:`_flux_form`).  Plain ``numba.njit(cache=True)``.
"""
from __future__ import annotations

import numpy as np
from numba import njit


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
def cram_pfd(lower, diag, upper, wl, wd, wu, t, y, c, theta, alpha0, want_d):  # pragma: no cover - numba
    """``exp(t L) y`` by CRAM-16 in partial fractions and with ``want_d`` its derivative in ``A`` (the balance bands
    ``W``: ``2 Re sum_j c_j M_j^-1 (t W) M_j^-1 y``); returns ``(x, dx, done)``.  ``done`` is False where a pole's
    elimination would interchange rows (LAPACK ``zgttrf``'s test) or a pivot leaves ``1e-150 ... 1e150``, and for
    ``t = 0`` or fewer than three states: the caller then takes the IPF form (:func:`._kernels.cram_apply`)."""
    if t == 0.0 or diag.size <= 2:
        return y.copy(), np.zeros(diag.size), False
    cw, r0 = flux_weights(c, theta, alpha0)
    return _pfd_dominant(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d)


#: poles per block of :func:`_pfd_dominant` (CRAM-16's 8; fewer poles leave lanes unused)
_LANES = 8
#: entries per row of :func:`_pfd_dominant`'s work array: ``_LANES`` each of the reciprocal pivot, the right-hand
#: side then solution, and the derivative's (real and imaginary parts)
_ROW = 6 * _LANES


@njit(cache=True, nogil=True, error_model="numpy")
def _pfd_dominant(lower, diag, upper, wl, wd, wu, t, y, c, cw, r0, theta, want_d):  # pragma: no cover - numba
    """:func:`cram_pfd` without row interchanges (``|d_i| >= |t l_i|`` in the 1-norm for every pole), the poles side
    by side: each row's values of :data:`_LANES` poles lie next to each other in one flat array, so the loops over
    the poles have no branch and LLVM vectorizes them.  Returns ``(x, dx, False)`` at the first row where a pole
    would interchange rows or a pivot leaves ``1e-150 ... 1e150``.
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
    """Forward elimination of :func:`_pfd_dominant` (``gs`` poles) into ``wk``; returns whether any pole needs a
    row interchange or the guarded division."""
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
def _flux_form(lower, upper, t, y, w, r0, out):  # pragma: no cover - numba
    """``out = r0 y + t L w`` with ``t L w`` as differences of the face fluxes ``F_i = t (lower_i w_i - upper_i
    w_{i+1})``: their sum telescopes, so probability is conserved to round-off whatever the error of ``w`` in
    stiff cells.

    The partial fractions ``alpha0 y + 2 Re sum_j c_j x_j`` equal ``r(0) y + t L w`` with ``w = 2 Re sum_j (c_j /
    theta_j) x_j``, since ``(t L - theta)^-1 = (t L (t L - theta)^-1 - 1)/theta``; ``L``'s columns sum to 0.
    ``out`` may be ``y``.
    """
    n = y.size
    prev = 0.0
    for i in range(n - 1):
        flux = t * (lower[i] * w[i] - upper[i] * w[i + 1])
        out[i] = r0 * y[i] + (prev - flux)
        prev = flux
    out[n - 1] = r0 * y[n - 1] + prev
