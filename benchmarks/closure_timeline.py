"""Where a closure call's time goes: the grids' integrations against the serial Python around them.

For each closure and Fig. 1 wall (``SelfAffineSpectrum(0.3, 2 pi/1024, 2 pi/32, rms_slope=0.031)``, ``E* = 8/3``,
``p0 = 0.004``, rtol 1e-6, default mode) the script times ``--calls`` warm calls with three engine functions
wrapped (``prepare``, ``_run_grids`` and the compiled stage kernel ``_Kernels.run_rows``; the wrappers cost a few
microseconds per call) and prints the medians of

* the whole call;
* the main problem's ``prepare`` (domain probe, Lamperti bound, grid family);
* the time outside the levels' grid integrations (``_run_grids``): closure problems, ``prepare``, grids, the
  regrading between levels, results and the shells' extrapolation, all in this thread, and at ``zeta <= 0.01``
  the shell ladder's plain solves beyond the main solve's grids (their kernels run outside ``_run_grids``);
* the time inside them;
* the compiled stage kernels' time in this thread and in the engine's worker thread.

It writes the table to ``results/closure_timeline.md`` (docs/closures.md "Where a call's time goes").

With ``--events CLOSURE ZETA`` it prints instead the events of the fastest of ``--calls`` warm calls of one cell,
thread by thread in time order (also the coefficient rows, the grid edges, the regrading, the remap and the results
records), and writes them to ``results/closure_events_<closure>_<zeta>.md``: where a thread waits for the other.

    python benchmarks/closure_timeline.py [--calls 15] [--events local_g1_balanced 0.1]
"""
from __future__ import annotations

import argparse
import functools
import os
import statistics
import threading
import time

import diffusion_pr as dp
from diffusion_pr.solvers.fv import engine

from bench_fokker_planck import SPECTRUM

ZETAS = (0.01, 0.1, 0.25, 1.0, 4.0)
CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")


def _instrument(events: list, detailed: bool = False) -> None:
    """Wrap the three engine functions so that each call appends ``(main thread?, start, end, label)``."""
    def wrap(owner, name: str, label: str) -> None:
        original = getattr(owner, name)

        @functools.wraps(original)
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                events.append((threading.current_thread() is threading.main_thread(), start, time.perf_counter(),
                               label))
        setattr(owner, name, timed)

    wrap(engine._Kernels, "run_rows", "kernel")
    wrap(engine, "_run_grids", "grids")
    wrap(engine, "prepare", "prepare")
    if detailed:
        for name, label in (("_coefficients", "coefficient rows"), ("edges_for", "edges"), ("_regraded", "regrade"),
                            ("_remapped", "remap"), ("build_result", "result record")):
            wrap(engine, name, label)


def warm_calls(closure: str, zeta: float, calls: int, events: list):
    """After 3 warm-up calls, ``calls`` timed calls of one cell: yields ``(seconds, start, events)`` per call
    (``events`` cleared before each)."""
    def solve():
        return dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure,
                                        rtol=1e-6)

    for _ in range(3):
        solve()
    for _ in range(calls):
        events.clear()
        t0 = time.perf_counter()
        solve()
        yield time.perf_counter() - t0, t0, events


def measure(closure: str, zeta: float, calls: int, events: list) -> list:
    """Medians [ms] of (call, main prepare, outside the grids, inside them, kernels here, kernels in the worker)."""
    per = []
    for total, _, evs in warm_calls(closure, zeta, calls, events):
        here = [e for e in evs if e[0]]
        inside = sum(b - a for _, a, b, lab in here if lab == "grids")
        prep = next(b - a for _, a, b, lab in here if lab == "prepare")  # the main problem's comes first
        k_here = sum(b - a for _, a, b, lab in here if lab == "kernel")
        k_worker = sum(b - a for m, a, b, lab in evs if lab == "kernel" and not m)
        per.append((total, prep, total - inside, inside, k_here, k_worker))
    return [1e3 * statistics.median(row[j] for row in per) for j in range(6)]


def event_lines(closure: str, zeta: float, calls: int, events: list) -> list:
    """The events of the fastest of ``calls`` warm calls, in time order: (thread, start, end, length [ms], label)."""
    best = None
    for total, t0, evs in warm_calls(closure, zeta, calls, events):
        if best is None or total < best[0]:
            best = (total, t0, list(evs))
    total, t0, evs = best
    busy = {m: sum(b - a for mm, a, b, lab in evs if mm == m and lab == "kernel") for m in (True, False)}
    lines = [f"`{closure}`, `zeta = {zeta:g}`: the fastest of {calls} warm calls, {1e3 * total:.2f} ms; kernels "
             f"{1e3 * busy[True]:.2f} ms in this thread, {1e3 * busy[False]:.2f} ms in the worker (load average "
             f"{os.getloadavg()[0]:.2f})", "", "| thread | from [ms] | to [ms] | length [ms] | what |",
             "|---|---|---|---|---|"]
    for m, a, b, lab in sorted(evs, key=lambda e: e[1]):
        lines.append(f"| {'main' if m else 'worker'} | {1e3 * (a - t0):.2f} | {1e3 * (b - t0):.2f} | "
                     f"{1e3 * (b - a):.2f} | {lab} |")
    return lines


def _write(name: str, lines: list) -> None:
    """``lines`` to ``results/<name>``, and say so."""
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", name)
    with open(out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calls", type=int, default=15)
    ap.add_argument("--events", nargs=2, metavar=("CLOSURE", "ZETA"), default=None,
                    help="print the events of one cell's fastest call instead of the table")
    args = ap.parse_args()
    events: list = []
    _instrument(events, detailed=args.events is not None)
    if args.events is not None:
        closure, zeta = args.events[0], float(args.events[1])
        lines = event_lines(closure, zeta, args.calls, events)
        print("\n".join(lines))
        _write(f"closure_events_{closure}_{zeta:g}.md", lines)
        return
    lines = [f"load average at the start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; medians of {args.calls} "
             "warm calls [ms]", "",
             "| closure | zeta | call | main prepare | outside the grids' integrations | inside them | "
             "kernels, this thread | kernels, worker |", "|---|---|---|---|---|---|---|---|"]
    for closure in CLOSURES:
        for zeta in ZETAS:
            m = measure(closure, zeta, args.calls, events)
            lines.append(f"| `{closure}` | {zeta:g} | " + " | ".join(f"{v:.1f}" for v in m) + " |")
            print(lines[-1], flush=True)
    _write("closure_timeline.md", lines)


if __name__ == "__main__":
    main()
