"""Warm closure solves with the kernels from their stored machine code against numba's dispatchers.

The same kernels' machine code is called either way (:mod:`diffusion_pr._machine_code`): through numba's dispatcher
(``DIFFUSION_PR_MACHINE_CODE=0``) or through the store's callable, which checks the arguments against the kernel's
one signature in Python and calls numba's own CPython wrapper. This script measures what that changes in warm calls,
and checks the answers bit for bit across the two processes.

For each closure and Fig. 1 wall (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, rtol 1e-6), each of ``--rounds`` rounds runs one fresh process per setting (alternating which goes
first), each timing ``--calls`` warm calls after one untimed call. Printed per cell: each setting's median over the
rounds' medians, the median of the rounds' ratios stored/numba with their range, whether numba was imported in the
stored process, and whether the answers (density, zero weight, estimate) are the same bits. Writes
``results/machine_code_ab.md``.

    python benchmarks/machine_code_ab.py [--rounds 3] [--calls 9] [--zetas 0.01 0.25 4]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parent / "results"

CHILD = r"""
import hashlib, json, statistics, sys, time
import numpy as np
import diffusion_pr as dp
S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
closure, zeta, calls = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
call = lambda: dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure, rtol=1e-6)
r = call()
times = []
for _ in range(calls):
    t = time.perf_counter()
    r = call()
    times.append(time.perf_counter() - t)
digest = hashlib.sha256(r.density.tobytes() + np.float64(r.zero_weight).tobytes()
                        + np.float64(r.error_estimate).tobytes()).hexdigest()
print(json.dumps(dict(median=statistics.median(times), digest=digest, numba="numba" in sys.modules)))
"""

SETTINGS = {"stored": "1", "numba": "0"}


def child(closure: str, zeta: float, setting: str, calls: int) -> dict:
    env = {**os.environ, "DIFFUSION_PR_MACHINE_CODE": SETTINGS[setting]}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, "-c", CHILD, closure, repr(zeta), str(calls)], capture_output=True,
                         text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calls", type=int, default=9)
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.01, 0.25, 4.0])
    ap.add_argument("--closures", nargs="+", default=["local_g1", "local_g1_balanced", "local_g1_shell_balanced"])
    args = ap.parse_args()
    lines = [f"# Warm closure solves: stored machine code against numba's dispatchers ({args.rounds} rounds of one "
             f"fresh process per setting, {args.calls} warm calls each; load {os.getloadavg()[0]:.2f})", "",
             "| closure | zeta | stored [ms] | numba [ms] | stored/numba | rounds' range | numba imported (stored) "
             "| same bits |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for closure in args.closures:
        for zeta in args.zetas:
            runs = {s: [] for s in SETTINGS}
            for rnd in range(args.rounds):
                for s in (list(SETTINGS) if rnd % 2 == 0 else list(SETTINGS)[::-1]):
                    runs[s].append(child(closure, zeta, s, args.calls))
            ratios = [a["median"] / b["median"] for a, b in zip(runs["stored"], runs["numba"])]
            same = len({r["digest"] for s in SETTINGS for r in runs[s]}) == 1
            cells = [f"`{closure}`", f"{zeta:g}",
                     *(f"{1e3 * statistics.median(r['median'] for r in runs[s]):.2f}" for s in ("stored", "numba")),
                     f"{statistics.median(ratios):.3f}", f"{min(ratios):.3f}-{max(ratios):.3f}",
                     "/".join(sorted({str(r["numba"]) for r in runs["stored"]})), "yes" if same else "**no**"]
            lines.append("| " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / "machine_code_ab.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
