"""Issue 10's closure target (every closure under 10 ms per Fig. 1 scene) judged in the competitor's units.

The issue states its targets in milliseconds of the day it was filed, when the independent competitor solved the
Fig. 1 scene at ``zeta = 0.25`` in 1.2 ms. This shared 2-core machine runs the same code 2-3x faster or slower from
day to day (docs/performance.md), so an absolute 10 ms is judged differently each day. This script times each
closure on the Fig. 1 scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, rtol 1e-6, two threads) interleaved with the competitor of ``fp_competitor.py`` (its own estimate,
rtol 1e-6) on that reference scene, in the same process, and reports:

* the closure's warm median [ms] and the competitor's;
* their ratio, against the target's ``10 / 1.2 = 8.3``: the 10 ms line in the competitor's units;
* the 10 ms line on this day, ``10 ms x competitor / 1.2 ms``.

The premise: the competitor built here from the issue's description runs as fast as the issue's (1.2 ms on its
day; 1.49 ms on this machine's fast day of the thirty-ninth session, 1.97-2.73 ms on the slow days after it), so
the normalization is approximate (within that 1.2-1.5x). Writes ``results/closures_vs_competitor.md``.

    python benchmarks/closures_vs_competitor.py [--repeats 7] [--zetas 4 1 0.25 0.1 0.01]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import diffusion_pr as dp

from bench_fokker_planck import OUT, SPECTRUM
from fp_competitor import adaptive, cases

CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")
#: the issue's numbers: the closure target and the competitor's time on the reference scene, its day [ms]
TARGET_MS, COMPETITOR_MS = 10.0, 1.2


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7, help="interleaved warm calls of each (default: 7)")
    ap.add_argument("--zetas", type=float, nargs="+", default=[4.0, 1.0, 0.25, 0.1, 0.01])
    args = ap.parse_args()
    problem, opts, _ = cases()["fig1-z0.25"]
    f, p0, V = problem.diffusivity, problem.mean_pressure, problem.variance

    def reference():
        return adaptive(1e-6, f, p0, V, **opts)

    line = TARGET_MS / COMPETITOR_MS
    rows = []
    load = os.getloadavg()[0]
    for closure in CLOSURES:
        for zeta in args.zetas:
            def solve(zeta=zeta, closure=closure):
                return dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,
                                                closure=closure, rtol=1e-6)

            res = solve()
            reference()
            solve()
            t_c, t_r = [], []
            for _ in range(args.repeats):
                for run, out in ((solve, t_c), (reference, t_r)):
                    t0 = time.perf_counter()
                    run()
                    out.append(time.perf_counter() - t0)
            c, r = 1e3 * statistics.median(t_c), 1e3 * statistics.median(t_r)
            rows.append((closure, zeta, c, r, c / r, TARGET_MS * r / COMPETITOR_MS, bool(res.success)))
            print(f"{closure:24s} zeta {zeta:6g}: {c:7.2f} ms, competitor {r:5.2f} ms, ratio {c / r:5.2f} "
                  f"(line {line:.1f}): {'under' if c / r <= line else 'over'}", flush=True)
    lines = [f"Load average at the start {load:.2f}; medians of {args.repeats} interleaved warm calls [ms]. The 10 ms "
             f"line in the competitor's units: {line:.1f} x its time on the Fig. 1 scene at zeta = 0.25 "
             f"(10 ms / {COMPETITOR_MS} ms on the issue's day).", "",
             "| closure | zeta | closure [ms] | competitor, Fig. 1 zeta 0.25 [ms] | ratio | 10 ms line today [ms] | "
             "under the line | success |", "|---|---|---|---|---|---|---|---|"]
    for closure, zeta, c, r, ratio, today, ok in rows:
        lines.append(f"| `{closure}` | {zeta:g} | {c:.2f} | {r:.2f} | {ratio:.2f} | {today:.1f} | "
                     f"{'yes' if ratio <= line else '**no**'} | {ok} |")
    OUT.mkdir(exist_ok=True)
    (OUT / "closures_vs_competitor.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT / 'closures_vs_competitor.md'}")


if __name__ == "__main__":
    main()
