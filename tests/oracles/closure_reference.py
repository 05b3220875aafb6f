r"""Independent reference solver for the shell-by-shell closures (an oracle, not a backend).

Solves, shell by shell in the diffusion time ``tau`` (pressure^2),

    dPr/dtau = d^2/dp^2 [ f(p, tau) Pr ] - d/dp [ b(p, tau) Pr ],     Pr(p, 0) = delta(p - p0),

with ``f = g(q(tau); p)^2`` and, for the load-balanced closure,
``b = (1 - g(q_part; p)) (f / p - A(tau) p)`` where the scalar ``A(tau)`` is
fixed at every step so that the discrete mean pressure stays exactly ``p0``
(docs/closures.md).  ``g(q; p) = 1 / (1 + zeta q E* / (2 p))``; ``q(tau)`` is the
shell schedule: shell ``k`` (wavenumber ``q_k``) occupies the ``tau`` interval of
length ``dV0_k / 2``.

Numerics (chosen for robustness, not speed; the production path is the
engine's staged solver, which this module checks):

* cell-centred finite volumes on ``[0, p_max]`` with edges ``p = s sinh(x)``,
  ``x`` uniform: cells of width about ``s dx`` near ``p = 0`` (``s`` resolves
  the scale ``zeta q_min E*/2`` where ``g`` switches off) and of relative width
  ``dx`` above ``s``;
* flux ``J = -d(fP)/dp + b P`` by Scharfetter-Gummel exponential fitting on
  ``u = f P`` (an M-matrix for every drift, exact for a locally constant
  ``b/f``); at ``p = 0`` zero flux when ``f(0) = 0`` (``zeta > 0``: the wall is
  never reached, ``ln p`` diffuses), an absorbing wall ``P(0) = 0`` when
  ``f(0) = 1`` (``zeta = 0``), whose outflow is the ``delta(p)`` weight;
* BDF2 in ``tau`` with a constant step (the first step implicit Euler); the
  operator of a step is the ``tau``-average of the shells' operators over a
  window of one step centred on the new time level (exact for piecewise
  constant schedules up to commutators, second order);
* for the balanced closure, ``A`` of each step by a secant iteration on the
  discrete mean (to 1e-13 relative).

Everything is at module level with ``numba.njit(cache=True)`` (no fastmath).
"""
from __future__ import annotations

import math
import time
from typing import Any, Optional

import numpy as np
from numba import njit


@njit(cache=True)
def _bern(x):  # pragma: no cover - numba
    """Bernoulli function ``B(x) = x / (exp(x) - 1)``, stable for all ``x``."""
    ax = abs(x)
    if ax < 1e-6:
        return 1.0 - 0.5 * x + x * x / 12.0
    if x > 700.0:
        return x * math.exp(-x)
    if x < -700.0:
        return -x
    return x / math.expm1(x)


@njit(cache=True)
def _thomas(lo, di, up, rhs, out, cp, dp):  # pragma: no cover - numba
    n = di.size
    cp[0] = up[0] / di[0]
    dp[0] = rhs[0] / di[0]
    for i in range(1, n):
        den = di[i] - lo[i] * cp[i - 1]
        cp[i] = up[i] / den if i < n - 1 else 0.0
        dp[i] = (rhs[i] - lo[i] * dp[i - 1]) / den
    out[n - 1] = dp[n - 1]
    for i in range(n - 2, -1, -1):
        out[i] = dp[i] - cp[i] * out[i + 1]


@njit(cache=True)
def _g(q, p, kz):  # pragma: no cover - numba
    """Local response ``g = 1/(1 + kz q / p)`` with ``kz = zeta E*/2`` (p > 0)."""
    if kz == 0.0:
        return 1.0
    return p / (p + kz * q)


@njit(cache=True)
def _assemble(edges, cen, wid, f_c, f_f, b1_f, w_f, A, absorbing, coef_dt, lo, di, up):  # pragma: no cover
    """Tridiagonal ``coef_dt * h_i - L`` for ``(L P)_i = J_i - J_{i+1}``; also returns nothing.

    ``lo, di, up`` receive ``-L``'s bands (``coef_dt`` times the cell width added to the diagonal).
    """
    n = cen.size
    for i in range(n):
        lo[i] = 0.0
        up[i] = 0.0
        di[i] = coef_dt * wid[i]
    if absorbing:
        di[0] += f_c[0] / cen[0]
    for j in range(1, n):
        d = cen[j] - cen[j - 1]
        v = (b1_f[j] - A * w_f[j]) / f_f[j]
        x = v * d
        bp = _bern(x)
        bm = bp + x  # B(-x) = B(x) + x
        alpha = bm / d  # coefficient of u_{j-1} in J_j
        beta = bp / d  # coefficient of u_j in J_j
        # (L P)_{j-1} gets -J_j; (L P)_j gets +J_j ; we store -L
        di[j - 1] += alpha * f_c[j - 1]
        up[j - 1] -= beta * f_c[j]
        lo[j] -= alpha * f_c[j - 1]
        di[j] += beta * f_c[j]


@njit(cache=True)
def _run(edges, cen, wid, P_init, q_sh, tau_sh, kz, q_part, balanced, absorbing, p0, n_steps, part_shell):  # pragma: no cover
    """BDF2 over the whole schedule; returns (P, zero_weight, A_last, max_secant_iterations, max_mean_residual)."""
    n = cen.size
    n_sh = q_sh.size
    tau_end = tau_sh[n_sh]
    dt = tau_end / n_steps
    P_old = P_init.copy()
    P_prev = P_init.copy()
    P_new = np.empty(n)
    rhs = np.empty(n)
    lo = np.empty(n)
    di = np.empty(n)
    up = np.empty(n)
    cp = np.empty(n)
    dpv = np.empty(n)
    f_c = np.empty(n)
    f_f = np.empty(n + 1)
    b1_f = np.zeros(n + 1)
    w_f = np.zeros(n + 1)
    zero = 0.0
    z_prev = 0.0
    A = 0.0
    max_sec = 0
    max_res = 0.0
    # partition factor (1 - g(q_part; p)) on faces: independent of the shell
    part_f = np.zeros(n + 1)
    if balanced:
        for j in range(1, n):
            part_f[j] = 1.0 - _g(q_part, edges[j], kz)
            w_f[j] = part_f[j] * edges[j]
    k_lo = 0
    for step in range(n_steps):
        t_new = (step + 1) * dt
        a = t_new - 0.5 * dt
        b = min(t_new + 0.5 * dt, tau_end)
        if step == n_steps - 1:
            a = t_new - 0.5 * dt
            b = tau_end
        # shell weights over [a, b]
        while k_lo < n_sh - 1 and tau_sh[k_lo + 1] <= a:
            k_lo += 1
        for i in range(n):
            f_c[i] = 0.0
        for j in range(n + 1):
            f_f[j] = 0.0
        span = b - a
        k = k_lo
        while k < n_sh and tau_sh[k] < b:
            ov = min(b, tau_sh[k + 1]) - max(a, tau_sh[k])
            if ov > 0.0:
                c = ov / span
                qk = q_sh[k]
                for i in range(n):
                    gg = _g(qk, cen[i], kz)
                    f_c[i] += c * gg * gg
                for j in range(1, n):
                    gg = _g(qk, edges[j], kz)
                    f_f[j] += c * gg * gg
            k += 1
        if balanced and not part_shell:
            for j in range(1, n):
                b1_f[j] = part_f[j] * f_f[j] / edges[j]
        if balanced and part_shell:
            # mutation for the tests: the partition at the shell's own q_k instead of q_min
            for j in range(n + 1):
                b1_f[j] = 0.0
                w_f[j] = 0.0
            k = k_lo
            while k < n_sh and tau_sh[k] < b:
                ov = min(b, tau_sh[k + 1]) - max(a, tau_sh[k])
                if ov > 0.0:
                    c = ov / span
                    for j in range(1, n):
                        gg = _g(q_sh[k], edges[j], kz)
                        b1_f[j] += c * (1.0 - gg) * gg * gg / edges[j]
                        w_f[j] += c * (1.0 - gg) * edges[j]
                k += 1
        # time discretization: first step IE, then BDF2 (constant step)
        if step == 0:
            coef = 1.0 / dt
            for i in range(n):
                rhs[i] = wid[i] * P_old[i] / dt
        else:
            coef = 1.5 / dt
            for i in range(n):
                rhs[i] = wid[i] * (2.0 * P_old[i] - 0.5 * P_prev[i]) / dt
        if not balanced:
            _assemble(edges, cen, wid, f_c, f_f, b1_f, w_f, 0.0, absorbing, coef, lo, di, up)
            _thomas(lo, di, up, rhs, P_new, cp, dpv)
        else:
            # secant on A for the discrete mean
            num = 0.0
            den = 0.0
            for j in range(1, n):
                pav = 0.5 * (P_old[j - 1] + P_old[j])
                num += b1_f[j] * pav * (cen[j] - cen[j - 1])
                den += w_f[j] * pav * (cen[j] - cen[j - 1])
            A0 = num / den if den > 0.0 else A
            if not math.isfinite(A0):
                A0 = A
            A1 = A0 + max(1e-3 * abs(A0), 1e-3 / (p0 * p0))
            _assemble(edges, cen, wid, f_c, f_f, b1_f, w_f, A0, absorbing, coef, lo, di, up)
            _thomas(lo, di, up, rhs, P_new, cp, dpv)
            m0 = 0.0
            for i in range(n):
                m0 += cen[i] * wid[i] * P_new[i]
            r0 = m0 - p0
            it = 0
            while abs(r0) > 1e-13 * p0 and it < 30:
                _assemble(edges, cen, wid, f_c, f_f, b1_f, w_f, A1, absorbing, coef, lo, di, up)
                _thomas(lo, di, up, rhs, P_new, cp, dpv)
                m1 = 0.0
                for i in range(n):
                    m1 += cen[i] * wid[i] * P_new[i]
                r1 = m1 - p0
                it += 1
                if r1 == r0:
                    A0 = A1
                    r0 = r1
                    break
                A2 = A1 - r1 * (A1 - A0) / (r1 - r0)
                A0 = A1
                r0 = r1
                A1 = A2
            # P_new holds the solution for A0 (the last one solved)
            A = A0
            if it > max_sec:
                max_sec = it
            if abs(r0) / p0 > max_res:
                max_res = abs(r0) / p0
        # zero weight (absorbing wall): outflow u_0 / c_0 at the new level
        if absorbing:
            out = f_c[0] * P_new[0] / cen[0]
            if step == 0:
                z_new = zero + dt * out
            else:
                z_new = (4.0 * zero - z_prev + 2.0 * dt * out) / 3.0
            z_prev = zero
            zero = z_new
        for i in range(n):
            P_prev[i] = P_old[i]
            P_old[i] = P_new[i]
    return P_old, zero, A, max_sec, max_res


def sinh_edges(s: float, p_max: float, n_cells: int) -> np.ndarray:
    """Edges ``s sinh(x)`` with ``x`` uniform on ``[0, asinh(p_max/s)]`` (pressure)."""
    x = np.linspace(0.0, math.asinh(p_max / s), n_cells + 1)
    e = s * np.sinh(x)
    e[0] = 0.0
    return e


def delta_start(edges: np.ndarray, p0: float) -> np.ndarray:
    """Density of ``delta(p - p0)`` split over the two cells whose centres bracket ``p0``:
    discrete mass 1 and discrete mean ``p0`` exactly."""
    cen = 0.5 * (edges[1:] + edges[:-1])
    wid = np.diff(edges)
    j = int(np.searchsorted(cen, p0)) - 1
    j = min(max(j, 0), cen.size - 2)
    t = (p0 - cen[j]) / (cen[j + 1] - cen[j])
    P = np.zeros(cen.size)
    P[j] = (1.0 - t) / wid[j]
    P[j + 1] = t / wid[j + 1]
    return P


def solve_reference(q_shells: np.ndarray, dV0: np.ndarray, *, zeta: float, E_star: float, mean_pressure: float,
                    balanced: bool, q_part: float | str | None = None, n_cells: int = 1200, n_steps: int = 2000,
                    scale: float | None = None, p_max: float | None = None, floor_factor: float = 0.25) -> dict:
    """Run the reference solver once on a given grid/step count.

    Parameters
    ----------
    q_shells : ndarray
        Shell wavenumbers [rad/length], in the order they are applied.
    dV0 : ndarray
        Persson increments [pressure^2] of the shells (``tau`` advances ``dV0/2``).
    zeta : float
        Wall range [length], >= 0 (0: hard wall, absorbing ``p = 0``).
    E_star, mean_pressure : float
        ``E*`` and ``p0`` [pressure].
    balanced : bool
        Load-balanced closure (drift with the multiplier ``A``).
    q_part : float or "shell", optional
        Wavenumber of the partition factor (default: smallest shell); ``"shell"``
        evaluates it at each shell's own ``q_k`` (a deliberate mutation for the tests).
    n_cells, n_steps : int
        Cells and BDF2 steps.
    scale, p_max : float, optional
        Near-wall scale ``s`` and domain end [pressure] (defaults from the scene).

    Returns
    -------
    dict
        ``edges``, ``density``, ``zero_weight``, ``A``, ``secant_iterations``, ``wall_time``.
    """
    q_shells = np.ascontiguousarray(q_shells, dtype=float)
    dV0 = np.ascontiguousarray(dV0, dtype=float)
    p0 = float(mean_pressure)
    kz = 0.5 * float(zeta) * float(E_star)
    if q_part is None:
        q_part = float(q_shells.min())
    part_shell = isinstance(q_part, str)
    if part_shell and q_part != "shell":
        raise ValueError(f"q_part must be a wavenumber or 'shell'; got {q_part!r}")
    if scale is None:
        scale = p0 / 20.0 if kz == 0.0 else min(p0 / 20.0, floor_factor * kz * float(q_shells.min()))
    if p_max is None:
        p_max = p0 + 10.0 * math.sqrt(float(dV0.sum()))
    edges = sinh_edges(scale, p_max, n_cells)
    cen = 0.5 * (edges[1:] + edges[:-1])
    wid = np.diff(edges)
    P = delta_start(edges, p0)
    tau = np.concatenate(([0.0], np.cumsum(0.5 * dV0)))
    t0 = time.perf_counter()
    Pf, zero, A, it, res = _run(edges, cen, wid, P, q_shells, tau, kz, 0.0 if part_shell else float(q_part),
                           bool(balanced), True, p0, int(n_steps), part_shell)
    return {"edges": edges, "density": Pf, "zero_weight": float(zero), "A": float(A),
            "secant_iterations": int(it), "mean_residual": float(res), "wall_time": time.perf_counter() - t0}


#: default resolution of the reference solver (cells, BDF2 steps); the error estimate
#: comes from a second run at half of both
REFERENCE_RESOLUTION = (1600, 1600)


def _solve_reference(shells: Any, *, zeta: float, E_star: float, p0: float, closure: str,
                     partition_q: Optional[float], n_cells: int, n_steps: int) -> Any:
    """The closure on ``shells`` solved by :func:`solve_reference` at two resolutions (the finer reported, their
    difference over 3 its error estimate)."""
    from diffusion_pr.result import PressureDistribution

    balanced = closure in ("local_g1_balanced", "local_g1_shell_balanced")
    if closure == "local_g1_shell_balanced":
        partition_q = "shell"
    t0 = time.perf_counter()
    runs = []
    # The wall floor (first edge) sits a factor `floor` below zeta q_min E*/2.  local_g1: ln p drifts
    # down at rate 1/p*^2 there, mass never returns, 1e-2 is deep enough.  Balanced: its drift
    # cancels that Ito drift, ln p random-walks over a wide range and mass comes back, so the floor
    # goes 32 e-folds deeper (1e-16) with the cells scaled to keep the cell size (docs/closures.md).
    floor = _balanced_floor() if balanced else 1e-2
    scale_cells = 1.0
    kz = 0.5 * zeta * E_star
    if balanced and kz > 0:
        pm = p0 + 10.0 * math.sqrt(shells.V0)
        s_shallow = min(p0 / 20.0, 1e-2 * kz * shells.q_min)
        s_deep = min(p0 / 20.0, floor * kz * shells.q_min)
        scale_cells = math.asinh(pm / s_deep) / math.asinh(pm / s_shallow)
    n_fine = 4 * int(math.ceil(n_cells * scale_cells / 4.0))
    for n, m in ((n_fine // 2, n_steps // 2), (n_fine, n_steps)):
        runs.append(solve_reference(shells.q, shells.dV0, zeta=zeta, E_star=E_star, mean_pressure=p0,
                                    balanced=balanced, q_part=partition_q if partition_q else shells.q_min,
                                    n_cells=n, n_steps=m, floor_factor=floor))
    coarse, fine = runs
    if fine["density"].size != 2 * coarse["density"].size:  # keep the grids nested
        raise RuntimeError("reference solver: non-nested grids")
    m_f = fine["density"] * np.diff(fine["edges"])
    m_c = coarse["density"] * np.diff(coarse["edges"])
    # nested grids (x uniform, halved): merge fine pairs; BDF2 and the grid are second order
    # the wall floor (first edge) moves with the grid: count the zero weight in the first coarse cell
    m_fc = m_f.reshape(-1, 2).sum(axis=1)
    m_fc[0] += fine["zero_weight"]
    m_c = m_c.copy()
    m_c[0] += coarse["zero_weight"]
    diff = float(np.sum(np.abs(m_fc - m_c)))
    err = diff / 3.0
    edges = fine["edges"]
    wall = time.perf_counter() - t0
    floor = float(edges[1])
    res_mean = fine["mean_residual"]
    density = fine["density"]
    n_neg = int(np.count_nonzero(density < 0))
    ok = n_neg == 0 and (not balanced or res_mean < 1e-10)
    msg = (f"reference solver: {n_fine} cells, {n_steps} BDF2 steps; estimated L1 error {err:.2e} "
           f"(against {n_fine // 2} cells/{n_steps // 2} steps)")
    if n_neg:
        msg += f"; {n_neg} negative cell densities (min {density.min():.3g})"
    if balanced and not res_mean < 1e-10:
        msg += f"; the multiplier A did not hold the mean (relative residual {res_mean:.3g}): NOT converged"
    diag = {"closure": closure, "n_cells": int(edges.size - 1), "n_steps": n_steps, "n_shells": int(shells.q.size),
            "partition_q": partition_q if partition_q else shells.q_min, "wall_floor": floor if kz > 0 else 0.0,
            "balance_multiplier": fine["A"], "secant_iterations": fine["secant_iterations"],
            "mean_residual": res_mean, "shells_exact": shells.exact}
    if kz > 0:
        diag["zero_weight_meaning"] = (f"mass below the wall floor {floor:.3g} (exponentially close to p = 0: "
                                       "g(q; p)^2 ~ p^2 never lets it reach 0)")
    return PressureDistribution(0.5 * (edges[1:] + edges[:-1]), density, np.diff(edges), fine["zero_weight"], p0,
                                shells.V0, "closure_reference", ok, msg, err, wall, diag, edges)

def reference_distribution(spectrum: Any, *, E_star: float, mean_pressure: float, zeta: float = 0.0,
                           closure: str = "local_g1_balanced", n_shells: Optional[int] = None,
                           partition_q: Any = None, n_cells: int = REFERENCE_RESOLUTION[0],
                           n_steps: int = REFERENCE_RESOLUTION[1]) -> Any:
    """A shell closure (``local_g1``, ``local_g1_balanced``, ``local_g1_shell_balanced``) of ``spectrum`` on
    ``n_shells`` uniform shells (:func:`diffusion_pr.closures.spectrum_shells`' default where None), solved by this
    module's reference solver at ``n_cells`` cells and ``n_steps`` BDF2 steps (each even, >= 16): the oracle the
    tests check the engine's closures against."""
    from diffusion_pr.closures import _BALANCED, _cached_shells, check_closure

    closure = check_closure(closure)
    if closure not in ("local_g1", *_BALANCED):
        raise ValueError(f"the reference solver solves the shell closures; got closure={closure!r}")
    for name, v in (("n_cells", n_cells), ("n_steps", n_steps)):
        if not isinstance(v, (int, np.integer)) or v < 16 or v % 2:
            raise ValueError(f"{name} must be an even integer >= 16; got {name}={v!r}")
    shells = _cached_shells(spectrum, float(E_star), n_shells, "uniform")
    return _solve_reference(shells, zeta=float(zeta), E_star=float(E_star), p0=float(mean_pressure), closure=closure,
                            partition_q=partition_q, n_cells=int(n_cells), n_steps=int(n_steps))


def _balanced_floor() -> float:
    from diffusion_pr.closures import BALANCED_FLOOR

    return BALANCED_FLOOR
