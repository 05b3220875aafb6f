"""Numba kernel of the compact fourth-order pencil's exponential (:mod:`.compact`).

:func:`pencil_pfd` is ``exp(t P^-1 Q) y`` for tridiagonal ``P`` and ``Q`` by CRAM in partial fractions, all
poles of a block eliminated together row by row, as the engine's :func:`._kernels.cram_pfd` eliminates
``t L - theta``; here all three bands of ``t Q - theta P`` are complex and the right-hand side is ``P y``.
Measured like for like against the engine's scalar kernel (``benchmarks/compact_kernel_cost.py``, 40-1280
cells, CRAM-16): 1.2-1.3x its time per exponential, with and without the balance derivative.

Module-level ``numba.njit(cache=True)``, no fastmath, numba's numpy error model (as :mod:`._kernels`).
Imported lazily (:func:`.compact.expm_pencil`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pencil_pfd", "POLE_BLOCK"]

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
def _accumulate(out, c, g0, x, n, gs):  # pragma: no cover - numba
    """``out += 2 Re sum_j c_j x_j`` over the block of poles from ``g0``."""
    for i in range(n):
        s = 0.0
        for jj in range(gs):
            cj = c[g0 + jj]
            s += cj.real * x[i, jj].real - cj.imag * x[i, jj].imag
        out[i] += 2.0 * s


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
