"""A boolean switch of :mod:`diffusion_pr.closures` on against off, the closure calls paired in one process.

``--flag SOLVE_AHEAD`` (the shell ladder's next rung integrated ahead on the worker's wait, forty-sixth session; the
default) or another boolean switch of ``diffusion_pr.closures``. For each closure and Fig. 1 wall
(``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``, ``p0 = 0.004``, rtol 1e-6) the
script first checks that both settings give the same answer bit for bit (density, zero weight, estimate, shells
solved), then times ``--rounds`` rounds of ``--pairs`` call pairs (on then off, then off then on, ...: a pair sees
the machine in one state; this machine's speed drifts by 10-30 % within minutes). Printed per cell: each setting's
median, the median of the pairs' ratios on/off and the range of the rounds' medians, and the shell counts solved
and left unused. Writes ``results/closures_<flag>_ab.md``.

    python benchmarks/closures_flag_ab.py [--flag SOLVE_AHEAD] [--rounds 3] [--pairs 11] [--zetas 0.001 0.01]
                                          [--closures local_g1_balanced local_g1_shell_balanced]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

import diffusion_pr as dp
from diffusion_pr import closures

from bench_fokker_planck import SPECTRUM


def _solve(closure: str, zeta: float):
    return dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure,
                                    rtol=1e-6)


def _same(a, b) -> bool:
    return bool(np.array_equal(a.density, b.density) and a.zero_weight == b.zero_weight
                and a.error_estimate == b.error_estimate
                and a.diagnostics.get("shells_solved") == b.diagnostics.get("shells_solved"))


def measure(flag: str, closure: str, zeta: float, rounds: int, pairs: int) -> dict:
    """The cell's times [s] per setting, the per-round medians of the pairs' ratios, and the answers' check."""
    out: dict = {"on": [], "off": [], "rounds": []}
    answers = {}
    for value in (True, False):
        setattr(closures, flag, value)
        answers[value] = _solve(closure, zeta)  # (also the warm-up)
    out["same"] = _same(answers[True], answers[False])
    out["solved"] = answers[True].diagnostics.get("shells_solved")
    out["unused"] = answers[True].diagnostics.get("shells_ahead_unused")
    for r in range(rounds):
        ratios = []
        for k in range(pairs):
            first = (k + r) % 2 == 0  # on first in every other pair
            t = {}
            for value in ((True, False) if first else (False, True)):
                setattr(closures, flag, value)
                t0 = time.perf_counter()
                _solve(closure, zeta)
                t[value] = time.perf_counter() - t0
            out["on"].append(t[True])
            out["off"].append(t[False])
            ratios.append(t[True] / t[False])
        out["rounds"].append(statistics.median(ratios))
    setattr(closures, flag, True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flag", default="SOLVE_AHEAD")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pairs", type=int, default=11)
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.001, 0.01, 0.1, 0.25])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    args = ap.parse_args()
    if not isinstance(getattr(closures, args.flag, None), bool):
        raise SystemExit(f"--flag must name a boolean switch of diffusion_pr.closures; got {args.flag!r}")
    default = getattr(closures, args.flag)
    lines = [f"`closures.{args.flag}` on against off (default {default}); load average at the start "
             f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; {args.rounds} rounds of {args.pairs} call pairs in one "
             "process (the order alternating); the ratio is the median of the pairs' ratios on/off, with the range of "
             "the rounds' medians", "",
             "| closure | zeta | on [ms] | off [ms] | ratio on/off | rounds | same bits | shells solved | unused |",
             "|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for closure in args.closures:
        for zeta in args.zetas:
            m = measure(args.flag, closure, zeta, args.rounds, args.pairs)
            ratio = statistics.median(a / b for a, b in zip(m["on"], m["off"]))
            lines.append(f"| `{closure}` | {zeta:g} | {1e3 * statistics.median(m['on']):.1f} | "
                         f"{1e3 * statistics.median(m['off']):.1f} | {ratio:.3f} | "
                         f"{min(m['rounds']):.3f}-{max(m['rounds']):.3f} | {m['same']} | {m['solved']} | "
                         f"{m['unused']} |")
            print(lines[-1], flush=True)
    setattr(closures, args.flag, default)
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                       f"closures_{args.flag.lower()}_ab.md")
    with open(out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
