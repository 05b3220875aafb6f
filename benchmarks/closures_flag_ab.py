"""A boolean switch of :mod:`diffusion_pr.closures` on against off, the closure calls paired in one process.

``--flag SOLVE_AHEAD`` (the shell ladder's next rung integrated ahead on the worker's wait, forty-sixth session; the
default) or another boolean switch of ``diffusion_pr.closures``. For each closure and Fig. 1 wall
(``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``, ``p0 = 0.004``, rtol 1e-6) the
script first checks that both settings give the same answer bit for bit (density, zero weight, estimate, shells
solved), then times ``--rounds`` rounds of ``--pairs`` call pairs (on then off, then off then on, ...: a pair sees
the machine in one state; this machine's speed drifts by 10-30 % within minutes). Printed per cell: each setting's
median, the median of the pairs' ratios on/off and the range of the rounds' medians, and the shell counts solved
and left unused. Writes ``results/closures_<flag>_ab.md``.

``--stress``: instead, the 320 default-mode scenes of ``stress_balance.py`` (four spectra, eight walls, five loads,
both balanced closures). Each is solved once with the switch on; for ``SOLVE_AHEAD`` only the scenes whose ladder
asked for a rung ahead are timed (3 pairs each), and the table splits them by whether the rung was wanted. Writes
``results/closures_<flag>_stress.md``.

    python benchmarks/closures_flag_ab.py [--flag SOLVE_AHEAD] [--rounds 3] [--pairs 11] [--zetas 0.001 0.01]
                                          [--closures local_g1_balanced local_g1_shell_balanced] [--stress]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

import diffusion_pr as dp
from diffusion_pr import closures
from diffusion_pr.solvers.fv import engine

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


def stress(flag: str, pairs: int = 3) -> list:
    """The stress scenes (``stress_balance.scenes``): per timed scene ``(name, closure, zeta, p0, asked, on, off)``
    with ``asked`` the answers of the ladder's ``wanted`` (SOLVE_AHEAD; empty for another switch: every scene
    timed) and the medians [s] of ``pairs`` pairs; a scene either setting fails on is skipped."""
    from stress_balance import scenes

    asked: list = []
    real = engine.plain_batch_ahead

    def spy(problems, ahead, wanted, **kwargs):
        def told(results):
            asked.append(bool(wanted(results)))
            return asked[-1]
        return real(problems, ahead, told, **kwargs)

    engine.plain_batch_ahead = spy
    rows = []
    try:
        for name, spec, closure, zeta, p0 in scenes():
            def solve():
                return closures.closure_distribution(spec, E_star=8 / 3, mean_pressure=p0, zeta=zeta, closure=closure)
            asked.clear()
            setattr(closures, flag, True)
            try:
                solve()
            except (RuntimeError, ValueError, FloatingPointError):
                continue
            if flag == "SOLVE_AHEAD" and not asked:
                continue
            got = list(asked)
            t: dict = {True: [], False: []}
            for k in range(pairs):
                for value in ((True, False) if k % 2 == 0 else (False, True)):
                    setattr(closures, flag, value)
                    t0 = time.perf_counter()
                    solve()
                    t[value].append(time.perf_counter() - t0)
            rows.append((name, closure, zeta, p0, got, statistics.median(t[True]), statistics.median(t[False])))
            print(f"{name[:24]:24s} {closure:24s} zeta {zeta:<6g} p0 {p0:<6g} asked {got} "
                  f"on/off {rows[-1][5] / rows[-1][6]:.3f}", flush=True)
    finally:
        engine.plain_batch_ahead = real
    return rows


def _stress_report(flag: str, rows: list) -> None:
    groups = [("all timed", rows), ("the rung ahead wanted", [r for r in rows if any(r[4])]),
              ("not wanted (cancelled)", [r for r in rows if r[4] and not any(r[4])])]
    lines = [f"`closures.{flag}` on against off over the stress scenes of `stress_balance.py` (default mode, rtol "
             f"1e-6); load average at the start {' '.join(f'{x:.2f}' for x in os.getloadavg())}; each timed scene "
             "the median of 3 pairs (the order alternating); ratio = summed on / summed off", "",
             "| scenes | count | on [s] | off [s] | ratio |", "|---|---|---|---|---|"]
    for label, rs in groups:
        if rs:
            on, off = sum(r[5] for r in rs), sum(r[6] for r in rs)
            lines.append(f"| {label} | {len(rs)} | {on:.2f} | {off:.2f} | {on / off:.3f} |")
    lines += ["", "| spectrum | closure | zeta | p0 | wanted | on [ms] | off [ms] | on/off |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r[0]} | `{r[1]}` | {r[2]:g} | {r[3]:g} | {r[4]} | {1e3 * r[5]:.1f} | {1e3 * r[6]:.1f} | "
              f"{r[5] / r[6]:.3f} |" for r in rows]
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", f"closures_{flag.lower()}_stress.md")
    with open(out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines[:8]))
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flag", default="SOLVE_AHEAD")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pairs", type=int, default=11)
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.001, 0.01, 0.1, 0.25])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    ap.add_argument("--stress", action="store_true", help="the stress scenes of stress_balance.py instead")
    args = ap.parse_args()
    if not isinstance(getattr(closures, args.flag, None), bool):
        raise SystemExit(f"--flag must name a boolean switch of diffusion_pr.closures; got {args.flag!r}")
    default = getattr(closures, args.flag)
    if args.stress:
        try:
            _stress_report(args.flag, stress(args.flag))
        finally:
            setattr(closures, args.flag, default)
        return
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
