"""The shell ladder's later rungs on the N grid alone (``closures.COARSE_RUNGS``), audited where they are used.

For the stress scenes of ``stress_balance.py`` (four spectra, eight walls, five loads, both balanced closures) and
``--random N`` scenes of ``stress_balance.random_scenes`` per ``--seeds``, every scene is solved at rtol 1e-6 with
the switch on; where its ladder used rungs on the N grid alone (``diagnostics["shells_on_the_coarse_grid"]``), it is
solved again with the switch off (the later rungs on both grids, the answer before the change) and at rtol 1e-8
(the oracle, on; ``stress_balance._l1_to``). Printed per such scene: the true L1 errors on and off, the estimates on
and off, the counted refinement error, the distance between the two answers, and both wall times (one call each:
the medians of 3 warm call pairs in alternating order). Writes ``results/coarse_rungs_audit.md``.

    python benchmarks/coarse_rungs_audit.py [--random 150] [--seeds 1 2] [--no-stress]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from diffusion_pr import closures
from diffusion_pr.closures import closure_distribution

import stress_balance as sb


#: warm call pairs per audited scene (on then off, then off then on, ...)
PAIRS = 3


def _solve(spec, closure, zeta, p0, rtol=1e-6, coarse=True):
    closures.COARSE_RUNGS = coarse
    try:
        t0 = time.perf_counter()
        r = closure_distribution(spec, E_star=8 / 3, mean_pressure=p0, zeta=zeta, closure=closure, rtol=rtol)
        return r, time.perf_counter() - t0
    except (RuntimeError, ValueError, FloatingPointError):
        return None, 0.0
    finally:
        closures.COARSE_RUNGS = True


def audit(scenes) -> list:
    rows = []
    for label, spec, closure, zeta, p0 in scenes:
        on, t_on = _solve(spec, closure, zeta, p0)
        if on is None or not on.success or not on.diagnostics.get("shells_on_the_coarse_grid"):
            continue
        off, t_off = _solve(spec, closure, zeta, p0, coarse=False)
        ref, _ = _solve(spec, closure, zeta, p0, rtol=1e-8)
        if off is None or ref is None or not ref.success or not np.array_equal(on.edges, off.edges):
            print("skipped (no oracle or other grids):", label, closure, zeta, p0, flush=True)
            continue
        times = {True: [], False: []}  # warm (the shells and problems cached by the calls above), alternating
        for k in range(PAIRS):
            for coarse in ((True, False) if k % 2 == 0 else (False, True)):
                times[coarse].append(_solve(spec, closure, zeta, p0, coarse=coarse)[1])
        t_on, t_off = statistics.median(times[True]), statistics.median(times[False])
        row = dict(label=label, closure=closure, zeta=zeta, p0=p0, rungs=on.diagnostics["shells_on_the_coarse_grid"],
                   true_on=sb._l1_to(on, ref), true_off=sb._l1_to(off, ref), est_on=on.error_estimate,
                   est_off=off.error_estimate, refinement=on.diagnostics["shell_refinement_error"],
                   moved=sb._l1_to(on, off), t_on=t_on, t_off=t_off, success_off=off.success)
        rows.append(row)
        flag = "  <<<" if row["true_on"] > 1e-6 or row["true_on"] > row["est_on"] or row["moved"] > row["refinement"] \
            else ""
        print(f"{label[:40]:40s} {closure[9:]:15s} zeta {zeta:<8.3g} p0 {p0:<8.3g} rungs {row['rungs']} true on/off "
              f"{row['true_on']:.2e}/{row['true_off']:.2e} est on/off {row['est_on']:.2e}/{row['est_off']:.2e} "
              f"moved {row['moved']:.2e} counted {row['refinement']:.2e} t on/off {1e3 * t_on:.0f}/{1e3 * t_off:.0f} ms"
              + flag, flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--random", type=int, default=150)
    ap.add_argument("--seeds", type=int, nargs="*", default=[1])
    ap.add_argument("--no-stress", action="store_true")
    args = ap.parse_args()
    sets = [] if args.no_stress else [("stress", ((f"{n} z {z:g} p0 {p:g}", s, c, z, p)
                                                 for n, s, c, z, p in sb.scenes()))]
    sets += [(f"random seed {seed}", ((f"#{i} {n}", s, c, z, p)
                                      for i, (n, s, c, z, p) in enumerate(sb.random_scenes(args.random, seed))))
             for seed in args.seeds]
    lines = ["# The later rungs on the N grid alone: audited where used", "",
             f"load average at the start {' '.join(f'{x:.2f}' for x in os.getloadavg())}; rtol 1e-6; oracle: the "
             "rtol-1e-8 answer (switch on); `moved`: L1 between the answers on and off; `counted`: the refinement's "
             "counted spatial error (`diagnostics['shell_refinement_error']`); times: medians of 3 warm call pairs, "
             "alternating", ""]
    for name, scenes in sets:
        print("##", name, flush=True)
        rows = audit(scenes)
        if not rows:
            lines += [f"## {name}: no scene used the coarse rungs", ""]
            continue
        lines += [f"## {name}: {len(rows)} scenes used the coarse rungs", "",
                  f"- true error above rtol: on {sum(r['true_on'] > 1e-6 for r in rows)}, off "
                  f"{sum(r['true_off'] > 1e-6 for r in rows)}; above the estimate: on "
                  f"{sum(r['true_on'] > r['est_on'] for r in rows)}, off {sum(r['true_off'] > r['est_off'] for r in rows)};"
                  f" above 3x it: on {sum(r['true_on'] > 3 * r['est_on'] for r in rows)}, off "
                  f"{sum(r['true_off'] > 3 * r['est_off'] for r in rows)}",
                  f"- the answers moved by more than the counted refinement error: "
                  f"{sum(r['moved'] > r['refinement'] for r in rows)}; largest moved/counted "
                  f"{max(r['moved'] / r['refinement'] for r in rows if r['refinement'] > 0):.2f}",
                  f"- summed time on {sum(r['t_on'] for r in rows):.2f} s, off {sum(r['t_off'] for r in rows):.2f} s "
                  f"({sum(r['t_on'] for r in rows) / sum(r['t_off'] for r in rows):.3f}x)", "",
                  "| scene | closure | zeta | p0 | rungs on N | true on | true off | est on | est off | moved | counted "
                  "| on [ms] | off [ms] |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['label']} | `{r['closure']}` | {r['zeta']:.3g} | {r['p0']:.3g} | {r['rungs']} | "
                  f"{r['true_on']:.2e} | {r['true_off']:.2e} | {r['est_on']:.2e} | {r['est_off']:.2e} | "
                  f"{r['moved']:.2e} | {r['refinement']:.2e} | {1e3 * r['t_on']:.0f} | {1e3 * r['t_off']:.0f} |"
                  for r in rows]
        lines.append("")
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "coarse_rungs_audit.md")
    with open(out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
