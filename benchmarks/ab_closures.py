"""Closure solve times of two versions of the package, measured in alternating processes (a before/after table).

Each round runs one fresh process per version (``--base``: a checkout of the earlier version, put first on
``PYTHONPATH``; the other process imports the package as installed), in turn, so that both see the machine in
the same state; each process times every closure on the Fig. 1 scene (``SelfAffineSpectrum(0.3, 2 pi/1024,
2 pi/32, rms_slope=0.031)``, ``E* = 8/3``, ``p0 = 0.004``, rtol 1e-6, default mode) as the median of
``--calls`` warm calls after one warm-up.  The table gives the medians over ``--rounds`` rounds, their ratio
and the coarsest grid's cells of each version.  Since the ninth session the default call answers the continuum
closure (Richardson in the number of shells); a base from before it solved the 96-shell problem, so such a pair
compares the price of that accuracy, not one computation.  The docs' before/after tables (docs/closures.md) come
from it:

    git worktree add /tmp/base <commit>
    python benchmarks/ab_closures.py --base /tmp/base [--rounds 3] [--calls 5]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

ZETAS = (0.001, 0.01, 0.1, 0.25, 1.0, 4.0)
CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")

CHILD = r"""
import json, sys
sys.path.insert(0, sys.argv[2])  # this folder: the timing helper of bench_fokker_planck
import diffusion_pr as dp
from bench_fokker_planck import SPECTRUM, timed
out = {}
for closure in %r:
    for zeta in %r:
        r, median = timed(lambda: dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,
                                                           closure=closure, rtol=1e-6), int(sys.argv[1]))
        out[f"{closure} {zeta:g}"] = [median, int(r.diagnostics["levels"][0]), bool(r.success)]
print(json.dumps(out))
""" % (CLOSURES, ZETAS)


def measure(pythonpath: str | None, calls: int) -> dict:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    here = os.path.dirname(os.path.abspath(__file__))
    run = subprocess.run([sys.executable, "-c", CHILD, str(calls), here], env=env, capture_output=True, text=True,
                         check=True, cwd="/")  # not the source tree: the installed package (or --base) is imported
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="path of the earlier version's checkout (put on PYTHONPATH)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calls", type=int, default=5)
    args = ap.parse_args()
    base, now = [], []
    for k in range(args.rounds):
        base.append(measure(args.base, args.calls))
        now.append(measure(None, args.calls))
        print(f"round {k + 1} of {args.rounds} done", file=sys.stderr, flush=True)
    print("| closure | zeta | before [ms] | now [ms] | ratio | cells (N) before/now |")
    print("|---|---|---|---|---|---|")
    for key in base[0]:
        b = statistics.median(r[key][0] for r in base)
        n = statistics.median(r[key][0] for r in now)
        closure, zeta = key.split()
        ok = "" if all(r[key][2] for r in base + now) else " (a solve failed)"
        print(f"| `{closure}` | {zeta} | {1e3 * b:.1f} | {1e3 * n:.1f} | {n / b:.2f} | "
              f"{base[0][key][1]}/{now[0][key][1]}{ok} |")


if __name__ == "__main__":
    main()
