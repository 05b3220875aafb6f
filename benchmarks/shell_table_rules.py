"""Candidate rules for the uniform shell table, each judged on the same scenes against the same oracles.

The uniform ladders among ``--random`` scenes per seed of ``--seeds`` (``stress_balance.random_scenes``) are solved
once at rtol 1e-8 (the oracles, kept in memory). Then each candidate rule replaces the uniform branch of
:func:`diffusion_pr.closures._shell_table` and every scene is solved again at rtol 1e-6. Printed per rule: the
ladders above their estimates, above rtol, above 2x rtol, the largest true/estimate, the summed time of the
solves (medians of ``--repeats``) and the shells they ended on. The Fig. 1 scenes at ``zeta`` = 0.1, 0.25, 1, 4 (the
closures' uniform ladders there) are timed with each rule too. A rule is a function of the table's ladder
``[P(n), P(n/2), P(n/4)(, P(n/8))]`` that returns ``(continuum, residual, diagnostics)``; ``shipped`` is the
package's, ``whole_ladder`` the one before the forty-ninth session (the base the forty-eighth session's candidates
modify; the results files of that session call it ``current``). Calibrate on some seeds, validate on others
(``--seeds``).

    python benchmarks/shell_table_rules.py [--random 250] [--seeds 17 18 19] [--rules whole_ladder shipped]
"""
from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from diffusion_pr import closures
from diffusion_pr.closures import closure_distribution

import stress_balance as sb
from bench_fokker_planck import SPECTRUM
from shell_table_audit import uniform_ladders

SHIPPED = closures._shell_table


def whole_ladder(ladder, thin=False, start=False):
    """The table before the forty-ninth session: the uniform rules on the whole vector of masses (no parts)."""
    if thin:
        return closures._thin_layer_table(ladder, start)
    return closures._uniform_table(ladder)


#: the base the candidate rules of the forty-eighth session modify (the table they were judged against)
CURRENT = whole_ladder


def _r(ladder):
    p_n, p_h, p_q = ladder[:3]
    return (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0


def romberg_floor(ladder, thin=False, start=False):
    """As shipped, but Romberg's residual at least the size of Romberg's own step ``|x_n - R_n|``."""
    x, residual, info = CURRENT(ladder, thin=thin, start=start)
    if thin or info.get("shell_extrapolation_order") != 6:
        return x, residual, info
    r_n, _ = _r(ladder)
    return x, max(residual, float(np.sum(np.abs(x - r_n)))), info


def _romberg_floor_over(k: float):
    def rule(ladder, thin=False, start=False):
        x, residual, info = CURRENT(ladder, thin=thin, start=start)
        if thin or info.get("shell_extrapolation_order") != 6:
            return x, residual, info
        r_n, _ = _r(ladder)
        return x, max(residual, float(np.sum(np.abs(x - r_n))) / k), info
    rule.__doc__ = f"As shipped, but Romberg's residual at least ``|x_n - R_n| / {k:g}``."
    return rule


def romberg_narrow(ladder, thin=False, start=False):
    """As shipped, but Romberg only on ``R`` ratios of 15-17 (else ``R`` with its own residual)."""
    if thin or len(ladder) < 4:
        return CURRENT(ladder, thin=thin, start=start)
    saved = closures.ROMBERG_RATIO
    closures.ROMBERG_RATIO = 15.0
    try:
        return CURRENT(ladder, thin=thin, start=start)
    finally:
        closures.ROMBERG_RATIO = saved


def r_divisor_8(ladder, thin=False, start=False):
    """As shipped, but ``R``'s residual divided by at most 7 (``min(rho, 8) - 1``) instead of 15."""
    x, residual, info = CURRENT(ladder, thin=thin, start=start)
    if thin or info.get("shell_extrapolation_order") != 4 or len(ladder) < 4:
        return x, residual, info
    r_n, r_h = _r(ladder)
    d_top = float(np.sum(np.abs(r_n - r_h)))
    rho = info.get("richardson_order_ratio", math.inf)
    return x, max(residual, d_top / max(min(rho, 8.0) - 1.0, 1.0)), info


def _uniform_part(ladder, part):
    """The shipped uniform table's verdict on one part of the masses: ``(romberg_ok, r_residual, romberg_residual)``."""
    p_n, p_h, p_q = (x[part] for x in ladder[:3])
    residual, rho_p, d_top = closures._shell_residual(p_n, p_h, p_q)
    if len(ladder) < 4:
        return False, residual, math.nan
    r_n, r_h = (4.0 * p_n - p_h) / 3.0, (4.0 * p_h - p_q) / 3.0
    r_q = (4.0 * p_q - ladder[3][part]) / 3.0
    d_half = float(np.sum(np.abs(r_h - r_q)))
    rho_r = d_half / d_top if d_top > 0.0 else math.inf
    if rho_r > closures.ROMBERG_MAX_RATIO:
        return False, max(residual, d_top), math.nan
    x_n, x_h = (16.0 * r_n - r_h) / 15.0, (16.0 * r_h - r_q) / 15.0
    ok = rho_p >= closures.SHELL_ORDER_RATIO and rho_r >= closures.ROMBERG_RATIO
    rho = rho_r if rho_p >= closures.SECOND_ORDER_CLEAR else min(rho_r, rho_p)
    return ok, max(residual, d_top / min(15.0, max(rho - 1.0, 1.0))), float(np.sum(np.abs(x_n - x_h))) / 15.0


def split_parts(ladder, thin=False, start=False):
    """As shipped, but the order observed on the zero weight and on the cells apart (as the thin layer's table
    does): Romberg only where both parts show it, each part's residual by its own ratios, summed."""
    x, residual, info = CURRENT(ladder, thin=thin, start=start)
    if thin or len(ladder) < 4:
        return x, residual, info
    parts = [_uniform_part(ladder, part) for part in (slice(0, 1), slice(1, None))]
    if all(ok for ok, _, _ in parts):
        return x, sum(r6 for _, _, r6 in parts), info
    p_n, p_h = ladder[:2]
    info = dict(info, shell_extrapolation_order=4, shell_weights=(4 / 3, -1 / 3, 0.0, 0.0))
    return (4.0 * p_n - p_h) / 3.0, sum(r4 for _, r4, _ in parts), info


def _part_table(ladder, part):
    """The uniform rules on one part of the masses alone: ``(continuum, residual, order)``."""
    x, residual, info = closures._uniform_table([m[part] for m in ladder])
    return x, residual, info["shell_extrapolation_order"]


def split_mixed(ladder, thin=False, start=False):
    """The uniform rules applied to the zero weight and to the cells apart (each its own order and residual, as
    the thin layer's table counts them); the continuum of each part from its own branch. Shipped since the
    forty-ninth session (``closures.UNIFORM_PARTS``): the same continuum and residual as ``shipped``."""
    x, residual, info = CURRENT(ladder, thin=thin, start=start)
    if thin or len(ladder) < 4:
        return x, residual, info
    (x0, r0, o0), (x1, r1, o1) = (_part_table(ladder, part) for part in (slice(0, 1), slice(1, None)))
    info = dict(info, shell_extrapolation_order=o1, zero_weight_order=o0,
                shell_weights=(64 / 45, -20 / 45, 1 / 45, 0.0) if o1 == 6 else (4 / 3, -1 / 3, 0.0, 0.0))
    return np.concatenate((x0, x1)), r0 + r1, info


RULES = {"shipped": SHIPPED, "whole_ladder": whole_ladder, "romberg_floor": romberg_floor, "romberg_floor_2": _romberg_floor_over(2.0),
         "romberg_floor_4": _romberg_floor_over(4.0), "romberg_narrow": romberg_narrow, "r_divisor_8": r_divisor_8,
         "split_parts": split_parts, "split_mixed": split_mixed}


def collect(seeds, n):
    """``[(label, spectrum, kwargs, oracle)]`` of the uniform ladders (shipped rule) among the random scenes."""
    out = []
    for seed in seeds:
        out += [(f"{seed}/{i}", spec, kw, ref) for i, _, spec, kw, _, ref in uniform_ladders(seed, n)]
        print(f"seed {seed}: {len(out)} uniform ladders so far", flush=True)
    return out


def judge(rule, scenes, repeats):
    closures._shell_table = rule
    try:
        rows = []
        for label, spec, kw, ref in scenes:
            times, r = [], None
            for _ in range(repeats):
                t0 = time.perf_counter()
                try:
                    r = closure_distribution(spec, **kw)
                except (RuntimeError, ValueError, FloatingPointError):
                    r = None
                times.append(time.perf_counter() - t0)
            if r is None or not r.success:
                rows.append((label, math.inf, math.nan, 0, statistics.median(times)))
                continue
            rows.append((label, sb._l1_to(r, ref), r.error_estimate, r.diagnostics["n_shells"][0],
                         statistics.median(times)))
        fig1 = []
        for closure in ("local_g1", "local_g1_balanced", "local_g1_shell_balanced"):
            for zeta in (0.1, 0.25, 1.0, 4.0):
                kw = dict(E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure)
                closure_distribution(SPECTRUM, **kw)
                ts = []
                for _ in range(max(repeats, 3)):
                    t0 = time.perf_counter()
                    r = closure_distribution(SPECTRUM, **kw)
                    ts.append(time.perf_counter() - t0)
                fig1.append((closure, zeta, r.diagnostics["n_shells"][0], statistics.median(ts)))
        return rows, fig1
    finally:
        closures._shell_table = CURRENT


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--random", type=int, default=250)
    ap.add_argument("--seeds", type=int, nargs="+", default=[17, 18, 19, 20, 21, 22])
    ap.add_argument("--rules", nargs="+", default=list(RULES), choices=list(RULES))
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    scenes = collect(args.seeds, args.random)
    lines = [f"# Uniform shell-table rules on {len(scenes)} uniform ladders (seeds {' '.join(map(str, args.seeds))}, "
             f"{args.random} random scenes each) and the Fig. 1 scenes", "",
             "| rule | above estimate | above rtol | above 2x rtol | largest true/estimate | summed time [s] | "
             "ladders on more shells than the first rule | Fig. 1 shells (zeta 0.1/0.25/1/4 per closure) | "
             "Fig. 1 summed time [ms] |", "|" + "---|" * 9]
    base = None
    for name in args.rules:
        rows, fig1 = judge(RULES[name], scenes, args.repeats)
        if base is None:
            base = {label: shells for label, _, _, shells, _ in rows}
        ratio = [t / e for _, t, e, _, _ in rows if e > 0 and math.isfinite(t)]
        more = sum(shells > base[label] for label, _, _, shells, _ in rows)
        line = (f"| {name} | {sum(t > e for _, t, e, _, _ in rows)} | {sum(t > 1e-6 for _, t, _, _, _ in rows)} | "
                f"{sum(t > 2e-6 for _, t, _, _, _ in rows)} | {max(ratio):.2f} | {sum(r[4] for r in rows):.2f} | "
                f"{more} | {' '.join(str(f[2]) for f in fig1)} | {1e3 * sum(f[3] for f in fig1):.0f} |")
        lines.append(line)
        print(line, flush=True)
    out = sb.RESULTS / f"shell_table_rules_{'_'.join(map(str, args.seeds))}.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
