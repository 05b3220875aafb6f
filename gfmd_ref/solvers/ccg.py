"""Constrained conjugate gradients for the hard wall (Polonsky & Keer 1999).

Polonsky & Keer, Wear 231, 206 (1999), doi:10.1016/S0043-1648(99)00113-1: conjugate
gradients on the pressures with the constraints ``p >= 0`` and ``mean(p) = p0``; the
displacement ``u = G p`` is computed from the pressure, so the force balance of every
mode holds by construction. Residual (relative to ``p0``, ``h_s`` the height scale):
``max(|<p> - p0|/p0, max|p g|/(p0 h_s), max(-g)_+/h_s)``: load error, complementarity,
penetration.
"""
from __future__ import annotations

import numpy as np

from . import _kernels as kr
from .monitor import Monitor

#: stall windows (iterations without halving the best residual) of ``ccg`` and ``pk``
CCG_STALL_WINDOW = 200
PK_STALL_WINDOW = 200
#: bound on the rounding of one single-precision ``G dv`` relative to its largest value
INCREMENT_ROUNDING = 2e-6
#: an exact ``u = G p`` is taken where the increments' rounding accumulated since the last
#: one could exceed this share of the residual (in units of ``h_scale``), after
#: :data:`REFRESH` increments, where the residual has not halved for
#: :data:`INCREMENT_STALL` iterations, and before convergence is declared
INCREMENT_SHARE = 1e-4
INCREMENT_STALL = 10
REFRESH = 50


def ccg(h, p0, el, tol, max_iter, progress, h_scale, precond=True):
    """Polonsky-Keer constrained CG on the pressures; returns the solver's answer dict.

    ``precond=True`` is ``method="ccg"`` (Fourier-diagonal preconditioner ``K = q E*/2``),
    ``precond=False`` is ``method="pk"``. The single-precision search and the ``u``
    increments with their rounding bound are described in docs/gfmd.md ("Methods").
    Start: uniform ``p0``.
    """
    n2 = h.size
    f32 = np.float32
    p = np.zeros(el.shape)  # the full grid pressure (for an exact u and the answer)
    u = np.zeros(el.shape)  # u = G p (a uniform pressure does not deform)
    index = np.int32 if n2 < 2 ** 31 else np.int64
    # the contact set, its sorted flat indices, and the pressure and direction packed in their order
    # (two lists each, swapped every step)
    c = np.ones(el.shape, dtype=np.bool_)
    idx, idx_next = np.arange(n2, dtype=index), np.empty(n2, dtype=index)
    pc, pc_next = np.full(n2, float(p0)), np.empty(n2)
    tc, tc_next = np.zeros(n2), np.empty(n2)
    nc = n2
    gcon = np.empty(n2)  # the gap on the contact set, in the order of idx
    ol, olg = np.empty(n2, dtype=index), np.empty(n2)  # overlaps (g < 0 off the set) and their gaps
    # single precision: the masked gap and K of it, the direction t, r = G t, the step's pressure change dv
    z32, t32, r32, dv32 = (np.zeros(el.shape, dtype=f32) for _ in range(4))
    Gn32 = el.Gn.astype(f32)
    Kn32 = (el.K / n2).astype(f32)
    psum = p0 * n2
    n_fft = n_single = n_increments = n_reused = 0
    delta, gold, it, since_exact = 0.0, 1.0, 0, 0
    u_rounding = 0.0  # the increments' rounding accumulated in u since the last exact u (bound)
    # the last step's increment of u, u <- scale (u + a gv), waits for the next gap pass
    fold, fold_scale, fold_a, fold_gv = False, 1.0, 1.0, dv32
    mon = Monitor("ccg" if precond else "pk", tol, max_iter, CCG_STALL_WINDOW if precond else PK_STALL_WINDOW,
                  progress)

    def residual():
        sg, gn, comp, pen, n_ol, gv_max = kr.pk_gap(u, h, pc, c, idx, nc, z32, precond, gcon, ol, olg, fold_gv,
                                                    fold_a, fold_scale, fold)
        load = abs(psum / n2 - p0) / p0
        return sg, gn, n_ol, max(load, comp / (p0 * h_scale), pen / h_scale), gv_max

    def exact_u():
        nonlocal n_fft, since_exact, u_rounding
        kr.scatter_contact(pc, idx, nc, p)
        el.fft.apply_route(el.Gn, p, u, dot=False)
        n_fft += 1
        since_exact, u_rounding = 0, 0.0

    while True:
        sg, gn, n_ol, res, gv_max = residual()
        if fold:
            u_rounding = fold_scale * (u_rounding + INCREMENT_ROUNDING * abs(fold_a) * gv_max)
            fold = False
        if mon.done(res, it) and since_exact > 0:  # every stop is judged on an exact u
            exact_u()
            sg, gn, n_ol, res, _ = residual()
        if mon.check(res, it):
            break
        zbar, gz = 0.0, gn  # pk: the direction from the gap itself
        if precond:  # z = K (masked g) in place; g.z over the contact set
            el.fft.apply_route(Kn32, z32, z32, dot=False)
            n_single += 1
            zsum, sgz = kr.contact_sums(z32, gcon, idx, nc)
            zbar = zsum / nc if nc > 0 else 0.0
            gz = sgz - zbar * sg  # sum_c g (z - zbar), the preconditioned residual norm
        beta = delta * gz / gold if gold > 0.0 else 0.0
        st, sgt = kr.pk_direction(z32, not precond, gcon, idx, nc, tc, zbar, beta, t32)
        gold = gz
        el.fft.apply_route(Gn32, t32, r32, dot=False)  # r = G t (the step length only)
        n_single += 1
        rsum, srt = kr.contact_sums(r32, tc, idx, nc)
        den = srt - (rsum / nc if nc > 0 else 0.0) * st  # sum_c (r - rbar) t
        tau = sgt / den if den != 0 else 0.0
        # increment u by G dv unless its rounding bound nears the residual, the residual stalls, or REFRESH ran
        use_incr = not (u_rounding > INCREMENT_SHARE * res * h_scale or since_exact + 1 >= REFRESH
                        or it - mon.it_best > INCREMENT_STALL)
        nc_before = nc
        nproj, psum, nc = kr.pk_step(pc, c, tc, idx, nc, ol, olg, n_ol, tau, idx_next, pc_next, tc_next, t32, dv32,
                                     use_incr)
        idx, idx_next = idx_next, idx
        pc, pc_next = pc_next, pc
        tc, tc_next = tc_next, tc
        if not psum > 0.0:  # the step removed every contact: no load can be restored
            mon.fail(f"a step removed every contact (sum p = {psum:g} after step {it + 1})")
            break
        scale = p0 * n2 / psum
        delta = 0.0 if n_ol > 0 else 1.0
        it += 1
        since_exact += 1
        psum = kr.pk_rescale(pc, nc, scale)
        if use_incr:
            n_increments += 1
            if nproj == 0 and nc == nc_before:  # the set kept: dv = -tau t, G dv = -tau r
                kr.zero_at(dv32, idx, nc)
                fold_gv, fold_a = r32, -tau
                n_reused += 1
            else:
                el.fft.apply_route(Gn32, dv32, dv32, dot=False)
                n_single += 1
                fold_gv, fold_a = dv32, 1.0
            fold, fold_scale = True, scale
        else:
            exact_u()
    kr.scatter_contact(pc, idx, nc, p)
    # displacement: z0 such that the gap vanishes on the contact set
    mask = p > 0
    z0 = float(np.mean((h - u)[mask])) if np.any(mask) else float(np.max(h - u))
    disp = u + z0
    return mon.outcome(it, pressure=p, gap=disp - h, displacement=disp,
                       info=dict(h_scale=h_scale, fft_pairs=n_fft + n_single, fft_pairs_single=n_single,
                                 u_increments=n_increments, u_increments_reusing_r=n_reused))
