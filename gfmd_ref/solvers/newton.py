"""Dual Newton-CG for the exponential wall.

Residual (relative to ``p0``): ``max_i |sigma(g_i) - p_el,i| / p0``, the force residual of
every node, with the wall pressure ``sigma = p0 exp(-g/zeta)`` (``v0 = zeta p0``).
"""
from __future__ import annotations

import math

import numpy as np

from . import _kernels as kr
from .monitor import Monitor

#: stall window (Newton steps without halving the best residual).
NEWTON_STALL_STEPS = 20
#: the inner CG's ``G d`` runs in single precision in a Newton step whose CG must reduce the
#: predicted residual by no more than this factor (float32 rounding of ``G d`` limits what the
#: CG can reach; below it, double)
SINGLE_CG_MIN_FORCING = 1e-5


def z0_residual(u: np.ndarray, h: np.ndarray, p: np.ndarray, p0: float, zeta: float,
                scratch: np.ndarray, keep: np.ndarray | None = None) -> tuple:
    """``(z0, residual)`` of the exponential wall, one exponential per node.

    ``z0 = zeta log(mean(exp(-(u - h)/zeta)))`` (log-sum-exp) and residual
    ``max |p0 exp(-(z0 + u - h)/zeta) - p| / p0``; ``scratch`` holds the exponentials,
    ``keep`` (made if None) marks where they are not ``+0``."""
    if keep is None:
        keep = np.empty(u.shape, dtype=np.bool_)
    m = kr.exp_exponents(u, h, zeta, scratch, keep)
    np.exp(scratch, out=scratch, where=keep)
    s, res = kr.exp_sum_residual(scratch, p, p0)
    return zeta * (m + math.log(s / h.size)), res


def newton(h, p0, zeta, el, tol, max_iter, progress):
    """Newton-CG on the dual (pressure) energy of the exponential wall.

    ``Phi(p) = mean(p u/2 - p h + zeta p log(p/p0))``, ``u = G p``, ``mean(p) = p0``; its
    minimiser is the equilibrium pressure. Projected PCG, multiplicative steps and the line
    search are described in docs/gfmd.md ("Methods"). ``G d`` runs in single precision
    where the forcing asks for no more than :data:`SINGLE_CG_MIN_FORCING`. Start: uniform ``p0``.
    """
    n2 = h.size
    pmin = max(p0 * 1e-300, 1e-300)
    shape = el.shape
    # the pressure and u = G p, and the CG direction d and G d, which the line search reuses for the trial
    # pressure and its u (the pairs swap names when a step is accepted)
    p, u, d, gd = (np.zeros(shape) for _ in range(4))
    d32, gd32 = np.zeros(shape, dtype=np.float32), np.zeros(shape, dtype=np.float32)
    Gn32 = el.Gn.astype(np.float32)
    p[...] = p0
    p *= p0 / p.mean()
    el.fft.apply_route(el.Gn, p, u, dot=False)
    grad, minv, wdiag, x, r, scratch, lp = (np.empty(shape) for _ in range(7))
    keep = np.empty(shape, dtype=np.bool_)  # where the wall's exponentials are not +0
    it = 0
    n_newton = cg_total = n_single = 0
    mon = Monitor("newton", tol, max_iter, NEWTON_STALL_STEPS, progress, step="Newton step")
    np.log(np.divide(p, p0, out=lp), out=lp)  # log(p/p0), then kept by every accepted step (its trial's)
    while True:
        E, E_scale = kr.dual_energy(u, h, p, lp, zeta, grad)
        z0, res = z0_residual(u, h, p, p0, zeta, scratch, keep)
        if mon.check(res, it, n_newton):
            break
        # inexact Newton direction by projected PCG on (G + diag(zeta/p)) x = -grad
        np.divide(zeta, p, out=wdiag)
        np.add(wdiag, el.g_diag, out=minv)
        np.divide(1.0, minv, out=minv)
        sum_minv = float(np.sum(minv))
        sum_p = float(np.sum(p))
        target = max(0.1 * res * min(1.0, res), 0.25 * tol)
        x[...] = 0.0
        np.negative(grad, out=r)
        rz, pred0 = kr.ncg_shift(r, minv, p, float(np.dot(minv.ravel(), r.ravel())) / sum_minv,
                                 float(np.dot(p.ravel(), r.ravel())) / sum_p)
        single = target >= SINGLE_CG_MIN_FORCING * pred0 / (zeta * p0)
        d[...] = 0.0
        dwd = kr.ncg_direction(d, r, minv, wdiag, 0.0, d32 if single else d)
        for _ in range(2000):
            if single:
                dAd = el.fft.apply_route(Gn32, d32, gd32) + dwd  # d.G d by Parseval, + d.diag d
                n_single += 1
            else:
                dAd = el.fft.apply_route(el.Gn, d, gd) + dwd
            it += 1
            cg_total += 1
            if dAd <= 0:
                break
            a = rz / dAd
            sm, sp = kr.ncg_update(x, r, d, gd32 if single else gd, wdiag, minv, p, a)
            rz_new, pred = kr.ncg_shift(r, minv, p, sm / sum_minv, sp / sum_p)
            if it >= max_iter or pred / (zeta * p0) <= target:
                break
            dwd = kr.ncg_direction(d, r, minv, wdiag, rz_new / rz, d32 if single else d)
            rz = rz_new
        # line search: the trial pressure and its u in the direction's arrays
        ptry, utry = d, gd
        slope = float(np.vdot(grad, x)) / n2
        alpha = 1.0
        for _ls in range(30):
            kr.dual_step(p, x, alpha, p0, pmin, ptry)
            el.fft.apply_route(el.Gn, ptry, utry, dot=False)
            it += 1
            Et, _ = kr.dual_energy(utry, h, ptry, np.log(np.divide(ptry, p0, out=lp), out=lp), zeta)
            if Et <= E + 1e-4 * alpha * slope:
                break
            # energy change at round-off of its terms (E_scale >> |E| near the solution): use the force residual
            if (abs(Et - E) <= 1e-11 * max(abs(E), E_scale)
                    and z0_residual(utry, h, ptry, p0, zeta, scratch, keep)[1] < (1.0 - 1e-4 * alpha) * res):
                break
            alpha *= 0.5
        else:
            mon.fail(f"stalled: the line search found no decrease of the dual energy in 30 halvings "
                     f"(round-off level); residual {res:.3e}")
            break
        p, d = ptry, p
        u, gd = utry, u
        n_newton += 1
    disp = u + z0  # z0 of this u: every exit leaves the loop after computing it, u unchanged since
    return mon.outcome(it, pressure=p, gap=disp - h, displacement=disp,
                       info=dict(newton_steps=n_newton, cg_iterations=cg_total, fft_pairs_single=n_single))
