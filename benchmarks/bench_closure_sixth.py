"""The shell closures with ``extrapolation="sixth"`` against the default (fourth order): warm time, true error, estimate.

Fig. 1 continuum scene (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, 96 shells), native backend, rtol 1e-6, two threads.  True error: L1 distance of the cell
masses and the zero weight from the engine's default solve at rtol 1e-9 (a converged finer run), and in
parentheses the largest cdf distance at 4000 pressures (between the output edges too).  The two
modes are timed call by call in turn (medians of ``--repeats`` warm calls), so they share the machine's
state.  Writes ``benchmarks/results/closure_sixth.md``.

    python benchmarks/bench_closure_sixth.py [--repeats 7] [--zetas 0.001,0.01,0.1,0.25,1,4]
    python benchmarks/bench_closure_sixth.py --sweep [--rounds 2]

``--sweep``: a 12-wall sweep (``zeta`` = 0.01 ... 4, geometric) per closure and mode, each wall solved
alone ("single") or by ``pressure_distributions`` ("chained": each wall started where the previous one's
estimate says, ``n_start`` and ``wall_grading``); total and median per wall (the solves' own timings) over
``--rounds`` rounds, levels integrated.  Writes
``benchmarks/results/closure_sweep.md``.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diffusion_pr as dp  # noqa: E402
from bench_fokker_planck import l1_against  # noqa: E402

SPEC = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
# the engine's schemes on the 96-shell problems (the continuum default adds the shell extrapolation on top)
KW = dict(E_star=8 / 3, mean_pressure=0.004, shell_extrapolation=False)
OUT = Path(__file__).resolve().parent / "results" / "closure_sixth.md"
OUT_SWEEP = Path(__file__).resolve().parent / "results" / "closure_sweep.md"
SWEEP_ZETAS = np.geomspace(0.01, 4.0, 12)


def cdf_error(ref, res) -> float:
    """The largest cdf distance from ``ref`` at 4000 pressures ``1e-12 p0 ... 1e3 p0`` (between edges too)."""
    x = np.geomspace(1e-12, 1e3, 4000) * KW["mean_pressure"]
    return float(np.max(np.abs(res.cdf(x) - ref.cdf(x))))


def _emit(lines: list, row: str) -> None:
    lines.append(row)
    print(row, flush=True)


def _write(path: Path, lines: list) -> None:
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


def sweep(closures, rounds: int) -> None:
    """The 12-wall sweep table (see the module docstring)."""
    lines = ["| closure | mode | start | total [ms] (rounds) | median per wall [ms] | levels over the walls |",
             "|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for cl in closures:
        for mode in ("fourth", "sixth"):
            for chained in (False, True):
                totals, per_wall = [], []
                for rnd in range(rounds + 1):  # round 0 warms up
                    opts = dict(closure=cl, rtol=1e-6, backend="native", extrapolation=mode, **KW)
                    t0 = time.perf_counter()
                    if chained:  # the package's sweep: each wall started where the previous one's estimate says
                        results = dp.pressure_distributions(SPEC, zetas=SWEEP_ZETAS, **opts)
                    else:
                        results = [dp.closure_distribution(SPEC, zeta=float(z), **opts) for z in SWEEP_ZETAS]
                    total = time.perf_counter() - t0
                    assert all(r.success for r in results), (cl, mode)
                    times = [r.diagnostics["timings"]["total"] for r in results]
                    levels = sum(len(r.diagnostics["history"]) for r in results)
                    if rnd:
                        totals.append(1e3 * total)
                        per_wall.append(1e3 * statistics.median(times))
                row = (f"| {cl} | {mode} | {'chained' if chained else 'single'} | "
                       f"{', '.join(f'{t:.0f}' for t in totals)} | {', '.join(f'{t:.1f}' for t in per_wall)} | "
                       f"{levels} |")
                _emit(lines, row)
    _write(OUT_SWEEP, lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--zetas", default="0.001,0.01,0.1,0.25,1,4")
    ap.add_argument("--closures", default="local_g1,local_g1_balanced,local_g1_shell_balanced")
    ap.add_argument("--sweep", action="store_true", help="the 12-wall sweep table instead")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    if args.sweep:
        sweep(args.closures.split(","), args.rounds)
        return
    modes = ("fourth", "sixth")
    lines = ["| closure | zeta | fourth: ms | sixth: ms | sixth / fourth | fourth: error (cdf error) [estimate] | "
             "sixth: error (cdf error) [estimate] | fourth: cells N, 2N, 4N | sixth: cells M, N, 2N, 4N (levels) | "
             "output cells |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for cl in args.closures.split(","):
        for zeta in (float(z) for z in args.zetas.split(",")):
            ref = dp.closure_distribution(SPEC, closure=cl, zeta=zeta, rtol=1e-9, **KW)

            def call(mode):
                return dp.closure_distribution(SPEC, closure=cl, zeta=zeta, rtol=1e-6, backend="native",
                                               extrapolation=mode, **KW)

            times = {m: [] for m in modes}
            res = {m: call(m) for m in modes}  # warm-up
            for _ in range(args.repeats):
                for m in modes:
                    t0 = time.perf_counter()
                    res[m] = call(m)
                    times[m].append(time.perf_counter() - t0)
            ms = {m: 1e3 * statistics.median(times[m]) for m in modes}
            f, s = res["fourth"], res["sixth"]
            assert f.success and s.success, (cl, zeta)
            row = (f"| {cl} | {zeta:g} | {ms['fourth']:.1f} | {ms['sixth']:.1f} | {ms['sixth'] / ms['fourth']:.2f} | "
                   f"{l1_against(ref, f):.1e} ({cdf_error(ref, f):.1e}) [{f.error_estimate:.1e}] | "
                   f"{l1_against(ref, s):.1e} ({cdf_error(ref, s):.1e}) [{s.error_estimate:.1e}] | "
                   f"{f.diagnostics['levels']} | {s.diagnostics['levels']} ({len(s.diagnostics['history'])}) | "
                   f"{f.edges.size - 1} / {s.edges.size - 1} |")
            _emit(lines, row)
    _write(OUT, lines)


if __name__ == "__main__":
    main()
