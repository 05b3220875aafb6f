"""Issue 10's closure target (every closure under 10 ms per Fig. 1 scene) judged in the competitor's units.

The issue states its targets in milliseconds of the day it was filed, when the independent competitor solved the
Fig. 1 scene at ``zeta = 0.25`` in 1.2 ms. This shared 2-core machine runs the same code 2-3x faster or slower from
day to day (docs/performance.md), so an absolute 10 ms is judged differently each day. This script times each
closure on the Fig. 1 scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, rtol 1e-6, two threads) interleaved with the competitor of ``fp_competitor.py`` (its own estimate,
rtol 1e-6) on that reference scene, in the same process, and reports:

* the closure's warm median [ms] and the competitor's;
* their ratio, against the target's ``10 / 1.2 = 8.3``: the 10 ms line in the competitor's units. Since the
  forty-second session each round's ratio is the median of the ratios of its call pairs (a closure call, then a
  competitor call: the two see the machine in one state), and the sweep is repeated in ``--rounds`` rounds: the
  table gives their median and range, and a closure is under the line only where every round is (the speed of this
  machine drifts within seconds: one sweep of medians moved a ratio by 10-20 %).

The premise: the competitor built here from the issue's description runs as fast as the issue's (1.2 ms on its
day; 1.49 ms on this machine's fast day of the thirty-ninth session, 1.97-2.73 ms on the slow days after it), so
the normalization is approximate (within that 1.2-1.5x). Writes ``results/closures_vs_competitor.md``.

    python benchmarks/closures_vs_competitor.py [--rounds 3] [--repeats 15] [--zetas 4 1 0.25 0.1 0.01]
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


def competitor_reference():
    """The competitor's solve of the Fig. 1 scene at ``zeta = 0.25`` (rtol 1e-6, its own estimate): the call every
    closure call is paired with."""
    problem, opts, _ = cases()["fig1-z0.25"]
    f, p0, V = problem.diffusivity, problem.mean_pressure, problem.variance
    return lambda: adaptive(1e-6, f, p0, V, **opts)


def paired_ratio(solve, reference, repeats: int, solve_times: list, reference_times: list) -> float:
    """The median over ``repeats`` warm call pairs (``solve``, then ``reference``) of their time ratio, after one
    warm-up call of each; the calls' times [s] are appended to the two lists."""
    reference()
    solve()
    pairs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        solve()
        t1 = time.perf_counter()
        reference()
        t2 = time.perf_counter()
        solve_times.append(t1 - t0)
        reference_times.append(t2 - t1)
        pairs.append((t1 - t0) / (t2 - t1))
    return statistics.median(pairs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=15, help="interleaved warm call pairs per round (default: 15)")
    ap.add_argument("--rounds", type=int, default=3, help="sweeps over all closures, one after the other (default: 3)")
    ap.add_argument("--zetas", type=float, nargs="+", default=[4.0, 1.0, 0.25, 0.1, 0.01])
    args = ap.parse_args()
    reference = competitor_reference()
    line = TARGET_MS / COMPETITOR_MS
    keys = [(closure, zeta) for closure in CLOSURES for zeta in args.zetas]
    times: dict = {k: ([], []) for k in keys}
    ratios: dict = {k: [] for k in keys}  # per round: the median of the pairs' ratios
    success: dict = {}
    load = os.getloadavg()[0]
    for rnd in range(args.rounds):
        for closure, zeta in keys:
            def solve(zeta=zeta, closure=closure):
                return dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,
                                                closure=closure, rtol=1e-6)

            success[closure, zeta] = bool(solve().success)
            t_c, t_r = times[closure, zeta]
            ratios[closure, zeta].append(paired_ratio(solve, reference, args.repeats, t_c, t_r))
            print(f"round {rnd + 1}: {closure:24s} zeta {zeta:6g}: ratio {ratios[closure, zeta][-1]:5.2f} "
                  f"(line {line:.1f})", flush=True)
    rows = []
    for closure, zeta in keys:
        t_c, t_r = times[closure, zeta]
        rr = ratios[closure, zeta]
        lo, mid, hi = min(rr), statistics.median(rr), max(rr)
        verdict = "yes" if hi <= line else "**no**" if lo > line else "at the line"
        rows.append((closure, zeta, 1e3 * statistics.median(t_c), 1e3 * statistics.median(t_r), mid, lo, hi, verdict,
                     success[closure, zeta]))
    lines = [f"Load average at the start {load:.2f}; {args.rounds} rounds (each a sweep over every closure) of "
             f"{args.repeats} interleaved warm call pairs (closure, then the competitor on the Fig. 1 scene at "
             f"zeta = 0.25). A round's ratio is the median of its pairs' ratios (a pair sees the machine in one "
             f"state); the table gives the median over the rounds and their range, and the medians of all calls "
             f"[ms]. The 10 ms line in the competitor's units: {line:.1f} (10 ms / {COMPETITOR_MS} ms on the issue's "
             f"day). Under the line: every round under it; at the line: the rounds on both sides.", "",
             "| closure | zeta | closure [ms] | competitor [ms] | ratio | rounds' range | under the line | success |",
             "|---|---|---|---|---|---|---|---|"]
    for closure, zeta, c, r, mid, lo, hi, verdict, ok in rows:
        lines.append(f"| `{closure}` | {zeta:g} | {c:.2f} | {r:.2f} | {mid:.2f} | {lo:.2f}-{hi:.2f} | {verdict} | "
                     f"{ok} |")
        print(f"{closure:24s} zeta {zeta:6g}: ratio {mid:5.2f} ({lo:.2f}-{hi:.2f}), line {line:.1f}: {verdict}")
    OUT.mkdir(exist_ok=True)
    (OUT / "closures_vs_competitor.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT / 'closures_vs_competitor.md'}")


if __name__ == "__main__":
    main()
