"""The uniform shell ladder's table against the truth: which branch it took, on what ratios, and how far off it was.

The forty-eighth session's fresh random audits (``stress_balance.py --truth --random 250`` with seeds 17-22, never
run before) found the closures' answers above rtol on 6 of about 1490 scenes, up to 5.9x; all but one on uniform
shells, where :func:`diffusion_pr.closures._shell_table` takes Romberg's column on an observed ratio of the
``R(n/2, n)`` differences in ``[ROMBERG_RATIO, ROMBERG_MAX_RATIO]`` or ``R(n/2, n)`` with its last difference over
``rho - 1``.  This script collects, for every random scene of ``--seeds`` whose answer at rtol 1e-6 came from a
uniform ladder, the table's inputs and verdict next to the truth (the rtol-1e-8 answer, ``stress_balance._l1_to``):

* the shells at the top and the branch (``shell_extrapolation_order``: 6 Romberg, 4 ``R``);
* the observed ratios ``rho_P`` (``shell_order_ratio``) and ``rho_R`` (``richardson_order_ratio``);
* the table's residual, the grids' estimate and the whole estimate;
* the true error and its ratio to the estimate.

The table is the data for recalibrating the uniform table on seeds that did not shape it (calibrate on some seeds,
validate on others). Writes ``results/shell_table_audit_<seeds>.md``.

    python benchmarks/shell_table_audit.py [--random 250] [--seeds 17 18 19 20 21 22]
"""
from __future__ import annotations

import argparse
import os

import numpy as np

from diffusion_pr.closures import closure_distribution

import stress_balance as sb

def uniform_ladders(seed: int, n: int):
    """Yields ``(index, name, spectrum, kwargs, answer, oracle)`` for the random scenes of ``seed`` (``n`` of them)
    whose rtol-1e-6 answer came from a uniform ladder and whose rtol-1e-8 answer (the oracle) succeeded."""
    for i, (name, spec, closure, zeta, p0) in enumerate(sb.random_scenes(n, seed)):
        kw = dict(E_star=8 / 3, mean_pressure=p0, zeta=zeta, closure=closure)
        try:
            r = closure_distribution(spec, **kw)
            if not r.success or r.diagnostics.get("shell_grading") != "uniform":
                continue
            ref = closure_distribution(spec, rtol=1e-8, **kw)
        except (RuntimeError, ValueError, FloatingPointError):
            continue
        if ref.success:
            yield i, name, spec, kw, r, ref


def audit(seed: int, n: int) -> list:
    """``[(seed, index, name, closure, zeta, p0, top shells, order, rho_P, rho_R, residual, grids, estimate,
    true)]`` of the uniform ladders among ``n`` random scenes of ``seed``."""
    rows = []
    for i, name, _, kw, r, ref in uniform_ladders(seed, n):
        d = r.diagnostics
        residual = d.get("shell_extrapolation_residual", np.nan)
        rows.append((seed, i, name, kw["closure"], kw["zeta"], kw["mean_pressure"], d["n_shells"][0],
                     d.get("shell_extrapolation_order"), d.get("shell_order_ratio", np.nan),
                     d.get("richardson_order_ratio", np.nan), residual, r.error_estimate - residual,
                     r.error_estimate, sb._l1_to(r, ref)))
        print(f"seed {seed} #{i} {kw['closure']:24s} zeta {kw['zeta']:.3g} shells {rows[-1][6]} order {rows[-1][7]} "
              f"rho_R {rows[-1][9]:.2f} true/est {rows[-1][13] / r.error_estimate:.2f}", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--random", type=int, default=250)
    ap.add_argument("--seeds", type=int, nargs="+", default=[17, 18, 19, 20, 21, 22])
    args = ap.parse_args()
    rows = [row for seed in args.seeds for row in audit(seed, args.random)]
    above_rtol = sum(row[13] > 1e-6 for row in rows)
    above_est = sum(row[13] > row[12] for row in rows)
    by_order = {}
    for row in rows:
        by_order.setdefault(row[7], []).append(row[13] / row[12])
    lines = [f"# The uniform shell table against the truth: {len(rows)} uniform ladders of {args.random} random scenes "
             f"per seed, seeds {' '.join(map(str, args.seeds))}", "",
             f"rtol 1e-6 against the rtol-1e-8 answer (L1 of the masses). Above rtol: {above_rtol}; above the estimate: "
             f"{above_est}. " + "; ".join(f"order {k}: {len(v)} ladders, true/estimate median {np.median(v):.2f}, "
                                         f"largest {max(v):.2f}" for k, v in sorted(by_order.items(), key=str)), "",
             "| seed | scene | spectrum | closure | zeta | p0 | shells | order | rho_P | rho_R | residual | grids | "
             "estimate | true | true/estimate |", "|" + "---|" * 15]
    for row in sorted(rows, key=lambda r: -r[13] / r[12]):
        seed, i, name, closure, zeta, p0, top, order, rho_p, rho_r, residual, grids, est, true = row
        lines.append(f"| {seed} | {i} | {name} | {closure} | {zeta:.4g} | {p0:.4g} | {top} | {order} | {rho_p:.2f} | "
                     f"{rho_r:.2f} | {residual:.2e} | {grids:.2e} | {est:.2e} | {true:.2e} | {true / est:.2f} |")
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                       f"shell_table_audit_{'_'.join(map(str, args.seeds))}.md")
    with open(out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines[:3]))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
