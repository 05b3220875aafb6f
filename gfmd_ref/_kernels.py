"""Real-space Numba kernels (module level, ``cache=True``, no fastmath).

All arrays are C-contiguous float64 ``(n, n)``; the kernels loop over the flat view.

Overflow guard: every exponential ``exp(x)`` of the exponential wall is evaluated
with ``x`` clamped to ``[EXP_MIN, EXP_MAX] = [-745, 700]``. ``exp(700) = 1.0e304``
stays finite (and so do sums of up to ~1e4 such values); ``exp(-745)`` underflows to
the smallest subnormal / zero, which is the physically right answer (no contact).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

EXP_MAX = 700.0
EXP_MIN = -745.0


@njit(cache=True)
def _clamp_exp(x):
    if x > EXP_MAX:
        x = EXP_MAX
    elif x < EXP_MIN:
        x = EXP_MIN
    return math.exp(x)


# --------------------------------------------------------------------------- hard wall, CCG


@njit(cache=True)
def pk_gap(u, h, p, g):
    """Gap ``g = u - h - gbar`` with ``gbar`` the mean of ``u - h`` over the contact set
    ``p > 0``. Returns ``(n_contact, sum_c g^2, max |p g|, max(-g) on p == 0, sum p)``."""
    uf = u.ravel()
    hf = h.ravel()
    pf = p.ravel()
    gf = g.ravel()
    n = uf.size
    s = 0.0
    nc = 0
    for i in range(n):
        if pf[i] > 0.0:
            s += uf[i] - hf[i]
            nc += 1
    gbar = s / nc if nc > 0 else 0.0
    gn = 0.0
    comp = 0.0
    pen = 0.0
    ps = 0.0
    for i in range(n):
        gi = uf[i] - hf[i] - gbar
        gf[i] = gi
        pi = pf[i]
        ps += pi
        if pi > 0.0:
            gn += gi * gi
            a = abs(pi * gi)
            if a > comp:
                comp = a
        elif -gi > pen:
            pen = -gi
    return nc, gn, comp, pen, ps


@njit(cache=True)
def pk_direction(g, p, t, beta):
    """``t = g + beta t`` on the contact set, 0 elsewhere."""
    gf = g.ravel()
    pf = p.ravel()
    tf = t.ravel()
    for i in range(gf.size):
        if pf[i] > 0.0:
            tf[i] = gf[i] + beta * tf[i]
        else:
            tf[i] = 0.0


@njit(cache=True)
def pk_masked(g, p, out):
    """``out = g`` on the contact set ``p > 0``, 0 elsewhere."""
    gf = g.ravel()
    pf = p.ravel()
    of = out.ravel()
    for i in range(gf.size):
        of[i] = gf[i] if pf[i] > 0.0 else 0.0


@njit(cache=True)
def pk_precond_direction(z, g, p, t, delta, gold):
    """Preconditioned Polonsky-Keer direction from ``z = K (masked g)``: on the contact
    set ``z' = z - mean_c(z)`` (so that a step along ``t`` keeps the load),
    ``t = z' + beta t`` with ``beta = delta (g . z') / gold``, 0 elsewhere.
    Returns ``g . z'`` (the next ``gold``)."""
    zf = z.ravel()
    gf = g.ravel()
    pf = p.ravel()
    tf = t.ravel()
    n = zf.size
    sz = 0.0
    sg = 0.0
    sgz = 0.0
    nc = 0
    for i in range(n):
        if pf[i] > 0.0:
            sz += zf[i]
            sg += gf[i]
            sgz += gf[i] * zf[i]
            nc += 1
    zbar = sz / nc if nc > 0 else 0.0
    gz = sgz - zbar * sg  # sum_c g (z - zbar); sum_c g ~ 0 (g has zero mean there)
    beta = delta * gz / gold if gold > 0.0 else 0.0
    for i in range(n):
        if pf[i] > 0.0:
            tf[i] = zf[i] - zbar + beta * tf[i]
        else:
            tf[i] = 0.0
    return gz


@njit(cache=True)
def pk_tau(g, t, r, p):
    """Step ``tau = sum_c g t / sum_c (r - rbar) t`` (contact set ``p > 0``), one pass:
    ``sum_c (r - rbar) t = sum_c r t - rbar sum_c t``. Returns (numerator, denominator)."""
    gf = g.ravel()
    tf = t.ravel()
    rf = r.ravel()
    pf = p.ravel()
    sr = 0.0
    st = 0.0
    srt = 0.0
    sgt = 0.0
    nc = 0
    for i in range(gf.size):
        if pf[i] > 0.0:
            ti = tf[i]
            sr += rf[i]
            st += ti
            srt += rf[i] * ti
            sgt += gf[i] * ti
            nc += 1
    rbar = sr / nc if nc > 0 else 0.0
    return sgt, srt - rbar * st


@njit(cache=True)
def pk_update(p, t, g, u, r, tau, p0):
    """Polonsky-Keer update, fused with the incremental displacement update:
    ``p -= tau t`` on the contact set, projected on ``p >= 0``; ``p = -tau g`` on
    non-contact points that overlap (``p == 0`` and ``g < 0``); ``u -= tau r``
    (``r = G t``); then ``p`` and ``u`` rescaled so that ``mean(p) = p0``.
    Returns ``(n_projected, n_overlap, scale)``: with no projection and no overlap,
    ``u = G p`` stays exact, otherwise ``u`` misses ``G`` of those changes."""
    pf = p.ravel()
    tf = t.ravel()
    gf = g.ravel()
    uf = u.ravel()
    rf = r.ravel()
    n = pf.size
    nproj = 0
    nol = 0
    s = 0.0
    for i in range(n):
        if pf[i] > 0.0:
            v = pf[i] - tau * tf[i]
            if v <= 0.0:
                v = 0.0
                nproj += 1
            pf[i] = v
        elif gf[i] < 0.0:
            pf[i] = -tau * gf[i]
            nol += 1
        s += pf[i]
        uf[i] = uf[i] - tau * rf[i]
    scale = p0 * n / s
    for i in range(n):
        pf[i] *= scale
        uf[i] *= scale
    return nproj, nol, scale


# --------------------------------------------------------------------------- exponential wall


@njit(cache=True)
def exp_log_mean(u, h, zeta):
    """``zeta * log(mean(exp(-(u - h)/zeta)))`` evaluated stably (log-sum-exp)."""
    uf = u.ravel()
    hf = h.ravel()
    n = uf.size
    m = -np.inf
    for i in range(n):
        x = -(uf[i] - hf[i]) / zeta
        if x > m:
            m = x
    s = 0.0
    for i in range(n):
        s += math.exp(-(uf[i] - hf[i]) / zeta - m)
    return zeta * (m + math.log(s / n))


@njit(cache=True)
def exp_pressure(z, h, p0, zeta, out):
    """``out = p0 exp(-(z - h)/zeta)`` with the exponent clamped (see module doc)."""
    zf = z.ravel()
    hf = h.ravel()
    of = out.ravel()
    for i in range(zf.size):
        of[i] = p0 * _clamp_exp(-(zf[i] - hf[i]) / zeta)


@njit(cache=True)
def exp_residual(u, h, z0, p, p0, zeta):
    """Max over nodes of ``|p0 exp(-(z0 + u - h)/zeta) - p| / p0``."""
    uf = u.ravel()
    hf = h.ravel()
    pf = p.ravel()
    r = 0.0
    for i in range(uf.size):
        s = p0 * _clamp_exp(-(z0 + uf[i] - hf[i]) / zeta)
        a = abs(s - pf[i])
        if a > r:
            r = a
    return r / p0


@njit(cache=True)
def dual_gradient(u, h, p, p0, zeta, grad):
    """Gradient of the dual energy: ``u - h + zeta (log(p/p0) + 1)``; returns the dual
    energy per node ``mean(p u / 2 - p h + zeta p log(p/p0))``."""
    uf = u.ravel()
    hf = h.ravel()
    pf = p.ravel()
    gf = grad.ravel()
    e = 0.0
    for i in range(uf.size):
        lp = math.log(pf[i] / p0)
        gf[i] = uf[i] - hf[i] + zeta * (lp + 1.0)
        e += 0.5 * pf[i] * uf[i] - pf[i] * hf[i] + zeta * pf[i] * lp
    return e / uf.size


@njit(cache=True)
def dual_energy(u, h, p, p0, zeta):
    uf = u.ravel()
    hf = h.ravel()
    pf = p.ravel()
    e = 0.0
    for i in range(uf.size):
        lp = math.log(pf[i] / p0)
        e += 0.5 * pf[i] * uf[i] - pf[i] * hf[i] + zeta * pf[i] * lp
    return e / uf.size


@njit(cache=True)
def dual_step(p, dp, alpha, p0, pmin, out):
    """Trial point along a Newton direction: linear where ``dp >= 0``, multiplicative
    ``p exp(alpha dp / p)`` where ``dp < 0`` (stays positive), floored at ``pmin``,
    rescaled to mean ``p0``."""
    pf = p.ravel()
    df = dp.ravel()
    of = out.ravel()
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


@njit(cache=True)
def proj_precond(r, minv, z):
    """Constraint-projected diagonal preconditioner. ``r`` is first shifted in place by
    the constant ``c = (w.r)/(sum w)``, ``w = M^-1 1`` (a constant gradient is in the
    null space of the constraint ``sum dp = 0``; removing it avoids cancellation),
    then ``z = M^-1 r`` has ``sum(z) = 0``. Returns ``r . z``."""
    rf = r.ravel()
    mf = minv.ravel()
    zf = z.ravel()
    n = rf.size
    a = 0.0
    b = 0.0
    for i in range(n):
        a += mf[i] * rf[i]
        b += mf[i]
    c = a / b
    rz = 0.0
    for i in range(n):
        v = rf[i] - c
        rf[i] = v
        zf[i] = mf[i] * v
        rz += v * zf[i]
    return rz


@njit(cache=True)
def newton_pred_residual(r, p, zeta, p0):
    """Predicted force residual of a Newton-CG iterate: ``max |p (r - c)| / (zeta p0)``
    with ``c = sum(p r)/sum(p)`` (a constant shift of the dual gradient is a shift of z0)."""
    rf = r.ravel()
    pf = p.ravel()
    a = 0.0
    b = 0.0
    for i in range(rf.size):
        a += pf[i] * rf[i]
        b += pf[i]
    c = a / b
    m = 0.0
    for i in range(rf.size):
        v = abs(pf[i] * (rf[i] - c))
        if v > m:
            m = v
    return m / (zeta * p0)


# --------------------------------------------------------------------------- FIRE helpers


@njit(cache=True)
def project_active(z, h, v, pel, contact):
    """Active-set hard wall for FIRE. A contact node (``contact[i]``) that still carries
    compression (``pel > 0``) stays on the wall (``z = h``, ``v = 0``): contact nodes
    only detach under tension. A free node that penetrates (``z < h``) is put on the
    wall and joins the contact set. Returns the number of contact nodes."""
    zf = z.ravel()
    hf = h.ravel()
    vf = v.ravel()
    pf = pel.ravel()
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


@njit(cache=True)
def hard_force(contact, pel, f):
    """Hard-wall projected force of a displacement field: a contact node carries ``max(p_el, 0)`` as wall reaction, so its net force is ``max(-p_el, 0)``
    (no tension); a free node feels ``-p_el``. Returns ``(max |f|, sum of reactions)``."""
    cf = contact.ravel()
    pf = pel.ravel()
    ff = f.ravel()
    r = 0.0
    s = 0.0
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
