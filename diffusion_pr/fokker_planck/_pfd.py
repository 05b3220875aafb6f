"""Numba kernels of CRAM-16 in partial fractions: ``exp(t L) y = alpha0 y + 2 Re sum_j c_j (t L - theta_j)^-1 y``.

:func:`cram_pfd` eliminates all poles' shifted tridiagonal systems together, row by row: first without row
interchanges (:func:`_pfd_dominant`, the poles of a row side by side so that LLVM runs the pole loops in vector
registers), and where a pole would need one, again with LAPACK ``zgttrf``'s partial pivoting
(:func:`_pfd_pivoting`); with the derivative in the balance multiplier ``A`` where asked.  The sum is written in
flux form (:func:`_flux_form`), so probability is conserved to round-off.  Plain ``numba.njit(cache=True)``.
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
