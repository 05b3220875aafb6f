"""GFMD with mass-weighted FIRE, for both walls.

Residuals (relative to ``p0``): hard wall (displacement variables, ``z >= h`` by
projection) ``max(|<p> - p0|/p0, max over free nodes |p_el|/p0, max over contact nodes
(-p_el)_+/p0)``, the force residual of every node (a free node must carry no pressure, a
contact node no tension); exponential wall ``max_i |sigma(g_i) - p_el,i| / p0``.
"""
from __future__ import annotations

import math

import numpy as np

from . import _kernels as kr
from .monitor import Monitor

#: stall window (steps without halving the best residual).
FIRE_STALL_WINDOW = 5000
#: FIRE's parameters (Bitzek et al. 2006): N_min, f_inc, f_dec, alpha_start, f_alpha
N_MIN, F_INC, F_DEC, A0, F_A = 5, 1.1, 0.5, 0.1, 0.99


def fire(h, p0, zeta, el, tol, max_iter, progress):
    """Mass-weighted FIRE dynamics of the Fourier modes of ``z`` (``zeta=None``: hard wall).

    Mode masses ``m(q) = q E*/2 + kappa`` and the wall handling: docs/gfmd.md ("Methods").
    """
    n2 = el.size
    hard = zeta is None
    kfloor = el.q1 * el.E_star / 2.0
    kappa = kfloor if hard else max(p0 / zeta, kfloor)
    K, w = el.K, el.w
    m = K + kappa
    kbar = float(np.sum(w * K)) / n2 + kappa
    # start: flat surface touching the highest point (hard) / carrying p0 (exp)
    if hard:
        z0 = float(h.max())
    else:  # zeta log(mean(exp(h/zeta))), log-sum-exp
        x = h / zeta
        z0 = zeta * (float(x.max()) + math.log(float(np.mean(np.exp(x - x.max())))))
    z = np.full(el.shape, z0)
    Z = el.rfft(z)
    V = np.zeros_like(Z)
    sig = np.empty(el.shape)
    freal = np.empty(el.shape)
    contact = np.zeros(el.shape, dtype=np.bool_)
    dt_max, dt, alpha, npos, it = 0.5, 0.1, A0, 0, 0
    mon = Monitor("fire", tol, max_iter, FIRE_STALL_WINDOW, progress)
    while True:
        # forces on the modes (unnormalised rfft units)
        if hard:
            pel = p0 + el.irfft(K * Z)
            fr, s = kr.hard_force(contact, pel, freal)
            res = max(fr / p0, abs(s / n2 - p0) / p0)
            F = el.rfft(freal)
        else:
            kr.exp_pressure(z, h, p0, zeta, sig)
            smax = float(sig.max())
            F = el.rfft(sig)
            F -= K * Z
            F[0, 0] -= p0 * n2
            res = float(np.max(np.abs(el.irfft(F)))) / p0
            dt_max = min(0.5, 0.9 / math.sqrt(1.0 + (smax / zeta) / kbar))
            dt = min(dt, dt_max)
        if mon.check(res, it):
            break
        P = float(np.sum(w * (F.real * V.real + F.imag * V.imag)))
        if P > 0:
            vn = math.sqrt(float(np.sum(w * m * (V.real**2 + V.imag**2))))
            fn = math.sqrt(float(np.sum(w * (F.real**2 + F.imag**2) / m)))
            V *= 1.0 - alpha
            if fn > 0:
                V += (alpha * vn / fn) * (F / m)
            npos += 1
            if npos > N_MIN:
                dt = min(dt * F_INC, dt_max)
                alpha *= F_A
        else:
            V[...] = 0.0
            dt *= F_DEC
            alpha = A0
            npos = 0
        V += (dt / m) * F
        Z += dt * V
        z = el.irfft(Z)
        if hard:
            v = el.irfft(V)
            kr.project_active(z, h, v, pel, contact)
            Z = el.rfft(z)
            V = el.rfft(v)
        it += 1
    if hard:
        pel = p0 + el.irfft(K * Z)
        p = np.where(contact & (pel > 0), pel, 0.0)
        gap = np.where(contact, 0.0, z - h)
        z = np.where(contact, h, z)
    else:
        kr.exp_pressure(z, h, p0, zeta, sig)
        p = sig
        gap = z - h
    s = p.mean()
    if s > 0:
        p *= p0 / s
    return mon.outcome(it, pressure=p, gap=gap, displacement=z,
                       info=dict(load_rescale=float(p0 / s) if s > 0 else float("nan"), final_dt=dt))
