"""Numba kernels of the compact fourth-order scheme (:mod:`.compact`): one exponential, and every stage of a grid.

:func:`pencil_pfd` is ``exp(t P^-1 Q) y`` for tridiagonal ``P`` and ``Q`` by CRAM in partial fractions, all
poles of a block eliminated together row by row, as the engine's :func:`._kernels.cram_pfd` eliminates
``t L - theta``; here all three bands of ``t Q - theta P`` are complex and the right-hand side is ``P y``.
Measured like for like against the engine's scalar kernel (``benchmarks/compact_kernel_cost.py``, 40-1280
cells, CRAM-16): 1.2-1.3x its time per exponential, with and without the balance derivative.

:func:`staged_run` is every stage of one grid in one call, the balance included, its rows made per Newton iterate
by :func:`pencil_rows`; at equal cells it costs 1.8-2.4x the engine's own staged kernel on the balanced closures
(``benchmarks/compact_staged.py``: the derivative taken with every exponential, the pencil's complex bands, no
vector lanes).

Module-level ``numba.njit(cache=True)``, no fastmath, numba's numpy error model (as :mod:`._kernels`).
Imported lazily (:func:`.compact.expm_pencil`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._kernels import _accumulate  # out += 2 Re sum_j c_j x_j over a block of poles

__all__ = ["pencil_pfd", "pencil_rows", "staged_run", "POLE_BLOCK"]

#: poles per block, as the engine's kernels take for CRAM-16 (two blocks of 4)
POLE_BLOCK = 4


@njit(cache=True, nogil=True, error_model="numpy")
def _band_product(lower, diag, upper, y, out):  # pragma: no cover - numba
    """``out = T y`` for the tridiagonal ``T`` of bands ``(lower, diag, upper)``."""
    n = diag.size
    for i in range(n):
        s = diag[i] * y[i]
        if i > 0:
            s += lower[i - 1] * y[i - 1]
        if i < n - 1:
            s += upper[i] * y[i + 1]
        out[i] = s


@njit(cache=True, nogil=True, error_model="numpy")
def pencil_pfd(pl, pd, pu, ql, qd, qu, q_row0, t, y, c, theta, alpha0, want_d, ppl, ppd, ppu, qql, qqd, qqu,
               qq_row0):  # pragma: no cover - numba
    """``exp(t P^-1 Q) y = alpha0 y + 2 Re sum_j c_j (t Q - theta_j P)^-1 P y`` (CRAM in partial fractions).

    Parameters
    ----------
    pl, pd, pu, ql, qd, qu : float64 arrays
        Lower (``n - 1``), diagonal (``n``) and upper (``n - 1``) bands of ``P`` and ``Q``.
    q_row0 : float64 array (2,)
        ``Q``'s first row beyond the band, its entries in columns 2 and 3 (a one-sided boundary row: the absorbing
        bottom of :mod:`.compact`; zeros for a tridiagonal ``Q``). The elimination then fills rows 0 and 1 with a
        second superdiagonal and row 0 with a third, and nothing else (``n >= 4``).
    t : float
        The time step (the units of ``Q``'s inverse rate).
    y : float64 array (n,)
        The state.
    c, theta : complex128 arrays
        Residues and poles of the partial fractions (one of each conjugate pair).
    alpha0 : float
        The rational function's value at infinity.
    want_d : bool
        Also the derivative in a multiplier ``a`` on which ``P`` and ``Q`` depend smoothly, their derivatives
        ``P_a`` and ``Q_a`` given as ``ppl, ppd, ppu`` and ``qql, qqd, qqu, qq_row0``:
        ``d x_j / da = (t Q - theta_j P)^-1 (P_a y - (t Q_a - theta_j P_a) x_j)``, a second solve with the
        stored elimination. Unused (any arrays of the right sizes) without ``want_d``.

    Returns
    -------
    (x, dx, info)
        ``x`` the result, ``dx`` its derivative (zeros without ``want_d``), ``info`` 0, or the first row
        (1-based) whose pivot vanished; no row is interchanged (the pencil's matrices are diagonally dominant
        where the engine's are).
    """
    n = pd.size
    m = theta.size
    g = POLE_BLOCK
    rec = np.empty((n, g), dtype=np.complex128)  # reciprocal pivots
    up = np.empty((n, g), dtype=np.complex128)  # the eliminated superdiagonal
    fl = np.empty((n, g), dtype=np.complex128)  # multipliers
    b = np.empty((n, g), dtype=np.complex128)
    r = np.empty((n if want_d else 1, g), dtype=np.complex128)
    v1 = np.zeros(g, dtype=np.complex128)  # row 1's fill in column 3 (from q_row0)
    fill = np.zeros(g, dtype=np.complex128)  # the fill added to the next row's superdiagonal
    py = np.empty(n)
    pay = np.empty(n)
    out = np.zeros(n)
    dout = np.zeros(n)
    _band_product(pl, pd, pu, y, py)
    if want_d:
        _band_product(ppl, ppd, ppu, y, pay)
    e2 = t * q_row0[0]  # row 0's entries in columns 2 and 3 (P has none there)
    e3 = t * q_row0[1]
    bordered = e2 != 0.0 or e3 != 0.0
    info = 0
    for g0 in range(0, m, g):
        gs = min(g, m - g0)
        for jj in range(gs):
            d0 = t * qd[0] - theta[g0 + jj] * pd[0]
            if d0.real == 0.0 and d0.imag == 0.0:
                return out, dout, 1
            rec[0, jj] = 1.0 / d0
            b[0, jj] = py[0]
            fill[jj] = 0.0
        for i in range(n - 1):
            tql = t * ql[i]
            tqu = t * qu[i]
            tqd = t * qd[i + 1]
            pli = pl[i]
            pui = pu[i]
            pdn = pd[i + 1]
            yn = py[i + 1]
            for jj in range(gs):
                th = theta[g0 + jj]
                u = (tqu - th * pui) + fill[jj]
                up[i, jj] = u
                f = (tql - th * pli) * rec[i, jj]
                fl[i, jj] = f
                dn = (tqd - th * pdn) - f * u
                if dn.real == 0.0 and dn.imag == 0.0:
                    info = i + 2
                    return out, dout, info
                rec[i + 1, jj] = 1.0 / dn
                b[i + 1, jj] = yn - f * b[i, jj]
                # row 0's columns 2 and 3 reach row 1 (-f e2 to its superdiagonal, -f e3 in column 3), and row
                # 1's column 3 reaches row 2's superdiagonal; nothing further down
                if i == 0:
                    fill[jj] = -f * e2
                    v1[jj] = -f * e3
                elif i == 1:
                    fill[jj] = -f * v1[jj]
                else:
                    fill[jj] = 0.0
        _back(rec, up, b, n, gs, bordered, e2, e3, v1)
        _accumulate(out, c, g0, b, n, gs)
        if not want_d:
            continue
        # the right-hand side P_a y - (t Q_a - theta P_a) x, eliminated with the stored multipliers
        for i in range(n):
            for jj in range(gs):
                th = theta[g0 + jj]
                v = (t * qqd[i] - th * ppd[i]) * b[i, jj]
                if i > 0:
                    v += (t * qql[i - 1] - th * ppl[i - 1]) * b[i - 1, jj]
                if i < n - 1:
                    v += (t * qqu[i] - th * ppu[i]) * b[i + 1, jj]
                if i == 0:
                    v += t * (qq_row0[0] * b[2, jj] + qq_row0[1] * b[3, jj])
                r[i, jj] = pay[i] - v
        for i in range(n - 1):
            for jj in range(gs):
                r[i + 1, jj] = r[i + 1, jj] - fl[i, jj] * r[i, jj]
        _back(rec, up, r, n, gs, bordered, e2, e3, v1)
        _accumulate(dout, c, g0, r, n, gs)
    for i in range(n):
        out[i] += alpha0 * y[i]
    return out, dout, info


@njit(cache=True, nogil=True, error_model="numpy")
def _back(rec, up, b, n, gs, bordered, e2, e3, v1):  # pragma: no cover - numba
    """Back substitution of :func:`pencil_pfd`'s elimination (``rec``: reciprocal pivots, ``up``: the eliminated
    superdiagonal; with ``bordered`` row 1's column-3 entry ``v1`` and row 0's ``e2``, ``e3``)."""
    for jj in range(gs):
        b[n - 1, jj] = b[n - 1, jj] * rec[n - 1, jj]
    for i in range(n - 2, -1, -1):
        for jj in range(gs):
            s = b[i, jj] - up[i, jj] * b[i + 1, jj]
            if bordered and i == 1:
                s -= v1[jj] * b[3, jj]
            elif bordered and i == 0:
                s -= e2 * b[2, jj] + e3 * b[3, jj]
            b[i, jj] = s * rec[i, jj]


@njit(cache=True, nogil=True, error_model="numpy")
def pencil_rows(h, a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, a_bal, a_bottom, pl, pd, pu, ql, qd, qu, ppl, ppd, ppu,
                 qql, qqd, qqu, row0):  # pragma: no cover - numba
    """The bands of ``P`` and ``Q`` (:func:`.compact.hoc_bands`) at the multiplier ``a_bal`` (``B = B_f + a_bal
    B_w``) into ``pl .. qu``, and their derivatives in it into ``ppl .. qqu`` (``P`` is linear in ``a_bal`` through
    ``beta``, ``Q`` quadratic); row 0 from ``a_bottom`` = ``(q00, q01, q02, q03)`` (:func:`.compact.absorbing_bottom`;
    zeros hold ``M_0``), its columns 2 and 3 into ``row0``; ``M`` held at the top. ``a .. bw2``: the rows of
    ``A, A', A'', B_f, .., B_w''`` at the interior nodes; ``h`` the spacing."""
    m = a.size
    n = m + 2
    for k in range(n - 1):
        pl[k] = 0.0
        pu[k] = 0.0
        ql[k] = 0.0
        qu[k] = 0.0
        ppl[k] = 0.0
        ppu[k] = 0.0
        qql[k] = 0.0
        qqu[k] = 0.0
    for k in range(n):
        pd[k] = 1.0
        qd[k] = 0.0
        ppd[k] = 0.0
        qqd[k] = 0.0
    h2_12 = h * h / 12.0
    inv_h2 = 1.0 / (h * h)
    inv_2h = 0.5 / h
    for i in range(m):
        k = i + 1
        b = bf[i] + a_bal * bw[i]
        b1 = bf1[i] + a_bal * bw1[i]
        b2 = bf2[i] + a_bal * bw2[i]
        ia = 1.0 / a[i]
        beta = (b - 2.0 * a1[i]) * ia
        beta_a = bw[i] * ia
        gamma = b2 + beta * b1
        gamma_a = bw2[i] + beta_a * b1 + beta * bw1[i]
        kappa = 2.0 * b1 + a2[i] + beta * (a1[i] + b)
        kappa_a = 2.0 * bw1[i] + beta_a * (a1[i] + b) + beta * bw[i]
        pl[k - 1] = 1.0 / 12.0 - beta * h / 24.0
        pd[k] = 5.0 / 6.0
        pu[k] = 1.0 / 12.0 + beta * h / 24.0
        ppl[k - 1] = -beta_a * h / 24.0
        ppu[k] = beta_a * h / 24.0
        d2 = (a[i] + h2_12 * kappa) * inv_h2
        d1 = (b + h2_12 * gamma) * inv_2h
        d2a = kappa_a / 12.0
        d1a = (bw[i] + h2_12 * gamma_a) * inv_2h
        ql[k - 1] = d2 - d1
        qd[k] = -2.0 * d2
        qu[k] = d2 + d1
        qql[k - 1] = d2a - d1a
        qqd[k] = -2.0 * d2a
        qqu[k] = d2a + d1a
    qd[0] = a_bottom[0]
    qu[0] = a_bottom[1]
    row0[0] = a_bottom[2]
    row0[1] = a_bottom[3]


@njit(cache=True, nogil=True, error_model="numpy")
def staged_run(h, a, a1, a2, bf, bf1, bf2, bw, bw1, bw2, bottom, dt, balanced, M, ww, p0, mean_tol, lin_tol, max_iter,
               c, theta, alpha0):  # pragma: no cover - numba
    """Every stage of one grid: ``M <- exp(dt_k P_k^-1 Q_k) M`` for the rows ``k`` of the coefficient arrays
    (:func:`pencil_rows`), with, where ``balanced[k]``, the multiplier ``A_k`` that puts the mean ``ww . M`` at
    ``p0`` at the stage's end (``|miss| <= mean_tol p0``); elsewhere ``A_k = 0``.

    The multiplier is predicted by the parabola through the last three stages' (the last one's, the second stage;
    0, the first), then Newton on the exact derivative (:func:`pencil_pfd`); once the miss is below ``lin_tol p0``
    the state takes the step to first order (``M + dA dM/dA``: mean exact, state error ``O(dA^2)``) without another
    exponential, as the engine's balance does. Returns ``(M, multipliers, n_exp, n_newton, info, stage)``:
    ``info`` 0; > 0 a vanished pivot; -1 the mean still missing after ``max_iter`` steps or not responding to
    ``A`` (``stage`` the failing stage, ``M`` the state before it).
    """
    n = M.size
    pl, pd, pu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ql, qd, qu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    ppl, ppd, ppu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    qql, qqd, qqu = np.empty(n - 1), np.empty(n), np.empty(n - 1)
    row0 = np.zeros(2)
    drow0 = np.zeros(2)
    hist = np.zeros(3)
    multipliers = np.zeros(dt.size)
    n_balanced = 0
    n_exp = 0
    n_newton = 0
    for k in range(dt.size):
        if not balanced[k]:
            pencil_rows(h, a[k], a1[k], a2[k], bf[k], bf1[k], bf2[k], bw[k], bw1[k], bw2[k], 0.0, bottom[k], pl, pd,
                        pu, ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
            x, _, info = pencil_pfd(pl, pd, pu, ql, qd, qu, row0, dt[k], M, c, theta, alpha0, False, ppl, ppd, ppu,
                                    qql, qqd, qqu, drow0)
            n_exp += 1
            if info != 0:
                return M, multipliers, n_exp, n_newton, info, k
            M = x
            continue
        if n_balanced >= 3:
            A = 3.0 * hist[0] - 3.0 * hist[1] + hist[2]
        elif n_balanced >= 1:
            A = hist[0]
        else:
            A = 0.0
        done = False
        for _ in range(max_iter):
            pencil_rows(h, a[k], a1[k], a2[k], bf[k], bf1[k], bf2[k], bw[k], bw1[k], bw2[k], A, bottom[k], pl, pd, pu,
                        ql, qd, qu, ppl, ppd, ppu, qql, qqd, qqu, row0)
            x, dx, info = pencil_pfd(pl, pd, pu, ql, qd, qu, row0, dt[k], M, c, theta, alpha0, True, ppl, ppd, ppu,
                                     qql, qqd, qqu, drow0)
            n_exp += 1
            if info != 0:
                return M, multipliers, n_exp, n_newton, info, k
            miss = -p0
            slope = 0.0
            for i in range(n):
                miss += ww[i] * x[i]
                slope += ww[i] * dx[i]
            if abs(miss) <= mean_tol * p0:
                M = x
                done = True
                break
            if slope == 0.0 or slope != slope:  # no response of the mean to A
                return M, multipliers, n_exp, n_newton, -1, k
            step = -miss / slope
            n_newton += 1
            A += step
            if abs(miss) <= lin_tol * p0:  # the last step to first order on the state
                for i in range(n):
                    x[i] += step * dx[i]
                M = x
                done = True
                break
        if not done:
            return M, multipliers, n_exp, n_newton, -1, k
        multipliers[k] = A
        hist[2] = hist[1]
        hist[1] = hist[0]
        hist[0] = A
        n_balanced += 1
    return M, multipliers, n_exp, n_newton, 0, -1
