"""Real-space Numba kernels of the contact solvers (``cache=True``, no fastmath).

numba's numpy error model: a division by zero gives IEEE inf/NaN. Grid arrays are
C-contiguous, looped over flat. The hard wall's contact-set fields are packed: ``pc[k]``,
``tc[k]``, ``gcon[k]`` belong to node ``idx[k]`` (``idx`` sorted). Exponents are clamped
to ``[EXP_MIN, EXP_MAX]`` (overflow guard, docs/gfmd.md).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

EXP_MAX = 700.0
EXP_MIN = -745.0


@njit(cache=True, error_model="numpy")
def _clamp_exp(x):
    if x > EXP_MAX:
        x = EXP_MAX
    elif x < EXP_MIN:
        x = EXP_MIN
    return math.exp(x)


# hard wall, CCG: one full pass per iteration (pk_gap), the rest touches only idx[:nc];
# the contact set is also kept as a mask c (c = p > 0)


@njit(cache=True, error_model="numpy")
def contact_sums(z, w, idx, nc):
    """``(sum_c z, sum_c w z)`` over the contact set ``idx[:nc]``, one pass (``w[k]`` packed:
    the value at ``idx[k]``; ``z`` may be single precision, sums in double)."""
    zf = z.ravel()
    s = d = 0.0
    for k in range(nc):
        v = float(zf[idx[k]])
        s += v
        d += w[k] * v
    return s, d


@njit(cache=True, error_model="numpy")
def pk_gap(u, h, pc, c, idx, nc, masked, want_masked, gcon, ol, olg, gv, a, scale, fold):
    """Gap ``g = u - h - gbar``, ``gbar`` the mean of ``u - h`` over the contact set.

    ``gcon[k]`` = ``g`` at ``idx[k]``; with ``want_masked``, ``masked = g`` on the set, 0
    elsewhere; the overlaps (``g < 0`` off the set) go to ``ol[:n_overlap]`` and ``olg``.
    With ``fold``, ``u = scale (u + a gv)`` first (the last step's increment), ``gv`` zeroed.
    Returns ``(sum_c g, sum_c g^2, max_c |p g|, max(-g) off the set, n_overlap, max |gv|)``."""
    uf, hf, cf, mf = u.ravel(), h.ravel(), c.ravel(), masked.ravel()
    gf = gv.ravel()
    s = 0.0
    for k in range(nc):
        i = idx[k]
        d = (scale * (uf[i] + a * float(gf[i])) if fold else uf[i]) - hf[i]
        gcon[k] = d
        s += d
    gbar = s / nc if nc > 0 else 0.0
    sg = gn = comp = 0.0
    for k in range(nc):
        gi = gcon[k] - gbar
        gcon[k] = gi
        sg += gi
        gn += gi * gi
        ap = abs(pc[k] * gi)
        if ap > comp:
            comp = ap
    pen = 0.0
    big = 0.0
    m = 0
    for i in range(uf.size):
        if fold:
            x = float(gf[i])
            ui = scale * (uf[i] + a * x)
            uf[i] = ui
            gf[i] = 0.0
            ax = abs(x)
            if ax > big:
                big = ax
        else:
            ui = uf[i]
        gi = ui - hf[i] - gbar
        on = cf[i]
        if want_masked:
            mf[i] = gi if on else 0.0
        if not on and gi < 0.0:
            if -gi > pen:
                pen = -gi
            ol[m] = i
            olg[m] = gi
            m += 1
    return sg, gn, comp, pen, m, big


@njit(cache=True, error_model="numpy")
def pk_direction(z, from_gap, gcon, idx, nc, tc, shift, beta, t2):
    """Polonsky-Keer direction on the contact set, packed (zero elsewhere): ``t = g + beta t``
    (``from_gap``, plain CG) or ``t = z - shift + beta t`` with ``z = K (masked g)`` and
    ``shift = mean_c z`` (a step along ``t`` keeps the load). ``t2`` (full grid) receives
    ``t`` for the step length's FFT. Returns ``(sum t, sum g t)``."""
    zf, t2f = z.ravel(), t2.ravel()
    st = sgt = 0.0
    for k in range(nc):
        x = gcon[k] if from_gap else zf[idx[k]] - shift
        v = x + beta * tc[k]
        tc[k] = v
        t2f[idx[k]] = v
        st += v
        sgt += gcon[k] * v
    return st, sgt


@njit(cache=True, error_model="numpy")
def pk_step(pc, c, tc, idx, nc, ol, olg, n_overlap, tau, idx_new, pc_new, tc_new, t2, dv, want_dv):
    """Polonsky-Keer step of the packed pressures: ``p -= tau t``, projected on ``p >= 0``.

    A projected node leaves the set; an overlap ``ol[m]`` joins it where ``-tau g > 0``
    (with ``t = 0``). One merge pass over both sorted lists writes the new set to
    ``idx_new``, ``pc_new``, ``tc_new``; with ``want_dv``, ``dv = p_new - p_old`` (float32)
    at every visited node. Returns ``(n_projected, sum p, new nc)``."""
    cf, t2f, vf = c.ravel(), t2.ravel(), dv.ravel()
    nproj = 0
    s = 0.0
    k = m = n = 0
    while k < nc or m < n_overlap:
        if m >= n_overlap or (k < nc and idx[k] < ol[m]):
            i = idx[k]
            pold = pc[k]
            told = tc[k]
            k += 1
            v = pold - tau * told
            if v <= 0.0:
                if want_dv:
                    vf[i] = -pold
                cf[i] = False
                t2f[i] = 0.0
                nproj += 1
                continue
            if want_dv:
                vf[i] = v - pold
            tc_new[n] = told
        else:
            i = ol[m]
            v = -tau * olg[m]
            m += 1
            if v <= 0.0:
                continue
            cf[i] = True
            if want_dv:
                vf[i] = v
            tc_new[n] = 0.0
        pc_new[n] = v
        s += v
        idx_new[n] = i
        n += 1
    return nproj, s, n


@njit(cache=True, error_model="numpy")
def pk_rescale(pc, nc, scale):
    """``pc[:nc] *= scale`` (the load back at ``p0``); returns the new ``sum p``."""
    s = 0.0
    for k in range(nc):
        v = pc[k] * scale
        pc[k] = v
        s += v
    return s


@njit(cache=True, error_model="numpy")
def zero_at(x, idx, nc):
    """``x[idx[k]] = 0`` for ``k < nc``."""
    xf = x.ravel()
    for k in range(nc):
        xf[idx[k]] = 0.0


@njit(cache=True, error_model="numpy")
def scatter_contact(pc, idx, nc, p):
    """The full grid of a packed field: ``p = 0``, then ``p[idx[k]] = pc[k]`` for ``k < nc``."""
    pf = p.ravel()
    pf[:] = 0.0
    for k in range(nc):
        pf[idx[k]] = pc[k]


# exponential wall


#: exp(x) rounds to +0 for every x below this (round-to-nearest gives 0 below exp(-745.13))
EXP_ZERO = -746.0


@njit(cache=True, error_model="numpy")
def exp_exponents(u, h, zeta, e, keep):
    """``e = x - m`` with the wall's exponents ``x = -(u - h)/zeta`` and their largest ``m``
    (returned). Below :data:`EXP_ZERO` ``e = 0`` and ``keep`` False, so numpy's
    ``exp(where=keep)`` skips libm's slow underflow path."""
    uf, hf, ef, kf = u.ravel(), h.ravel(), e.ravel(), keep.ravel()
    m = -np.inf
    for i in range(uf.size):
        x = -(uf[i] - hf[i]) / zeta
        if x > m:
            m = x
    for i in range(uf.size):
        v = -(uf[i] - hf[i]) / zeta - m
        if v < EXP_ZERO:
            ef[i] = 0.0
            kf[i] = False
        else:
            ef[i] = v
            kf[i] = True
    return m


@njit(cache=True, error_model="numpy")
def exp_sum_residual(e, p, p0):
    """From ``e = exp(x - m)`` (:func:`exp_exponents`): ``(s, residual)``, ``s = sum e`` and
    the force residual ``max |sigma - p| / p0`` with the wall pressure ``sigma = p0 exp(-(z0
    + u - h)/zeta) = p0 e n / s`` (never overflows: ``e <= 1``, ``n/s <= n``)."""
    ef, pf = e.ravel(), p.ravel()
    n = ef.size
    s = 0.0
    for i in range(n):
        s += ef[i]
    scale = p0 * n / s
    r = 0.0
    for i in range(n):
        a = abs(scale * ef[i] - pf[i])
        if a > r:
            r = a
    return s, r / p0


@njit(cache=True, error_model="numpy")
def exp_pressure(z, h, p0, zeta, out):
    """``out = p0 exp(-(z - h)/zeta)`` with the exponent clamped (see module doc)."""
    zf, hf, of = z.ravel(), h.ravel(), out.ravel()
    for i in range(zf.size):
        of[i] = p0 * _clamp_exp(-(zf[i] - hf[i]) / zeta)


@njit(cache=True, error_model="numpy")
def dual_energy(u, h, p, lp, zeta, grad=None):
    """The dual energy per node ``mean(p u/2 - p h + zeta p lp)`` (``lp = log(p/p0)``) and the
    mean magnitude of its terms: near the solution the energy is a small difference of
    those terms, so its round-off scales with the magnitude. With ``grad``, also writes the
    gradient ``u - h + zeta (lp + 1)`` there."""
    uf, hf, pf, lf = u.ravel(), h.ravel(), p.ravel(), lp.ravel()
    if grad is not None:
        gf = grad.ravel()
    e = a = 0.0
    for i in range(uf.size):
        if grad is not None:
            gf[i] = uf[i] - hf[i] + zeta * (lf[i] + 1.0)
        t1 = 0.5 * pf[i] * uf[i]
        t2 = pf[i] * hf[i]
        t3 = zeta * pf[i] * lf[i]
        e += t1 - t2 + t3
        a += abs(t1) + abs(t2) + abs(t3)
    return e / uf.size, a / uf.size


@njit(cache=True, error_model="numpy")
def dual_step(p, dp, alpha, p0, pmin, out):
    """Trial point along a Newton direction: linear where ``dp >= 0``, multiplicative
    ``p exp(alpha dp / p)`` where ``dp < 0`` (stays positive), floored at ``pmin``,
    rescaled to mean ``p0``."""
    pf, df, of = p.ravel(), dp.ravel(), out.ravel()
    n = pf.size
    s = 0.0
    for i in range(n):
        if df[i] >= 0.0:
            v = pf[i] + alpha * df[i]
        else:
            v = pf[i] * _clamp_exp(alpha * df[i] / pf[i])
        if v < pmin:
            v = pmin
        of[i] = v
        s += v
    sc = p0 * n / s
    for i in range(n):
        v = of[i] * sc
        if v < pmin:
            v = pmin
        of[i] = v


@njit(cache=True, error_model="numpy")
def ncg_update(x, r, d, gd, wdiag, minv, p, a):
    """One projected-CG update, one pass: ``x += a d``, ``r -= a (gd + wdiag d)`` (``gd = G d``).
    Returns ``(sum minv r, sum p r)`` of the new ``r`` (the shifts of :func:`ncg_shift`)."""
    xf, rf, df, gf = x.ravel(), r.ravel(), d.ravel(), gd.ravel()
    wf, mf, pf = wdiag.ravel(), minv.ravel(), p.ravel()
    sm = sp = 0.0
    for i in range(xf.size):
        di = df[i]
        xf[i] += a * di
        v = rf[i] - a * (gf[i] + wf[i] * di)
        rf[i] = v
        sm += mf[i] * v
        sp += pf[i] * v
    return sm, sp


@njit(cache=True, error_model="numpy")
def ncg_shift(r, minv, p, c, cp):
    """``r -= c``: project the diagonal preconditioner on ``sum dp = 0``.

    ``c = (minv.r)/sum minv`` makes ``z = minv r`` sum to 0. Returns ``(r.z, max |p (r -
    cp)|)``, ``cp = sum p r / sum p`` before the shift: the preconditioned norm and the
    predicted force residual times ``zeta p0``."""
    rf, mf, pf = r.ravel(), minv.ravel(), p.ravel()
    rz = m = 0.0
    for i in range(rf.size):
        v = rf[i]
        e = abs(pf[i] * (v - cp))
        if e > m:
            m = e
        v -= c
        rf[i] = v
        rz += v * (mf[i] * v)
    return rz, m


@njit(cache=True, error_model="numpy")
def ncg_direction(d, r, minv, wdiag, beta, d2):
    """``d = minv r + beta d``, one pass; ``d2`` receives a copy (the single-precision input
    of the next FFT, or ``d`` itself). Returns ``sum wdiag d^2``, the diagonal part of ``d.A d``."""
    df, d2f, rf, mf = d.ravel(), d2.ravel(), r.ravel(), minv.ravel()
    wf = wdiag.ravel()
    s = 0.0
    for i in range(df.size):
        v = mf[i] * rf[i] + beta * df[i]
        df[i] = v
        d2f[i] = v
        s += wf[i] * v * v
    return s


# FIRE


@njit(cache=True, error_model="numpy")
def project_active(z, h, v, pel, contact):
    """Active-set hard wall: a contact node under compression (``pel > 0``) stays on the wall
    (``z = h``, ``v = 0``; nodes detach only under tension), a free node that penetrates
    joins it. Returns the number of contact nodes."""
    zf, hf, vf, pf = z.ravel(), h.ravel(), v.ravel(), pel.ravel()
    cf = contact.ravel()
    nc = 0
    for i in range(zf.size):
        if (cf[i] and pf[i] > 0.0) or zf[i] < hf[i]:
            zf[i] = hf[i]
            vf[i] = 0.0
            cf[i] = True
            nc += 1
        else:
            cf[i] = False
    return nc


@njit(cache=True, error_model="numpy")
def hard_force(contact, pel, f):
    """Hard-wall projected force: 0 on a compressed contact node, ``-p_el`` elsewhere.
    Returns ``(max |f|, sum of reactions)``."""
    cf, pf, ff = contact.ravel(), pel.ravel(), f.ravel()
    r = s = 0.0
    for i in range(pf.size):
        if cf[i] and pf[i] > 0.0:
            s += pf[i]
            ff[i] = 0.0
        else:
            ff[i] = -pf[i]
            a = abs(pf[i])
            if a > r:
                r = a
    return r, s
