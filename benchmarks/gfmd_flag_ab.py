"""GFMD hard wall, ``ccg``: one switch of ``gfmd_ref.solver`` on against off, in fresh processes or in one.

``--flag INCREMENT_U32`` (``u`` updated by the single-precision ``G dv`` between exact ``u = G p`` against an exact
``u`` after every step; the default) or another boolean switch of ``gfmd_ref.solver`` (``SINGLE_STEP``,
``SINGLE_PRECOND``, ``INCREMENT_REUSE_R``, ``FOLD_INCREMENT``); every other switch keeps its default.
(``STEP_PARSEVAL``, measured with it in the forty-third session, was reverted:
``results/gfmd_step_parseval_1024.md``.) Each variant runs in its own fresh process, the two alternating, ``--rounds``
times per surface; a process makes its plans, solves once to warm up, then ``--repeats`` times, and reports the median
of those warm solves (wall time without planning), the iterations and the pressure. Printed per surface: the
iterations, the medians of each variant, the ratio of the medians of the rounds, the per-round ratios (each round's
two processes ran back to back), and the largest pressure difference between the variants' answers (in ``p0``).

    python benchmarks/gfmd_flag_ab.py [--flag INCREMENT_U32] [--n 1024] [--seeds 1 2 3] [--rounds 3] [--repeats 3]
                                      [--tol 1e-8] [--in-process]

Writes ``results/gfmd_<flag>_<n>.md`` (e.g. ``gfmd_increment_u32_<n>.md``).

``--in-process``: both variants in this process, the switch flipped between solves, ``rounds x repeats`` pairs per
surface (on/off, then off/on, ...) after one warm-up solve; printed per surface the median of the pairs' ratios
on/off with its quartiles and the ratio of the medians. On days when fresh processes of the same code scattered by
1.8-3.1 s at 1024² (the forty-fourth session), this resolved the packed layout's 5-10 %, not the reused ``r``'s
3-5 %. It also gives each solve's time less its transforms and multiplies (the solve's own timers,
``info["fft_seconds"]``): where a switch changes no FFT pair (``FOLD_INCREMENT``), that ratio is free of the
transforms' drift. Writes ``results/gfmd_<flag>_<n>_inproc.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
E_STAR, P0 = 8.0 / 3.0, 0.004

CHILD = r"""
import json, sys, numpy as np
import gfmd_ref as g
from gfmd_ref import solver
n, seed, tol, flag = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4] == "1"
repeats, out, name = int(sys.argv[5]), sys.argv[6], sys.argv[7]
setattr(solver, name, flag)
for k, v in json.loads(sys.argv[8]).items():  # the limits _lifted lifts for this switch
    setattr(solver, k, v)
h, L = g.fig1_surface(n, seed=seed)
times = []
for k in range(repeats + 1):
    r = g.solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=g.HardWall(), tol=tol, method="ccg")
    assert r.converged, r.message
    if k:
        times.append(r.wall_time - r.info["fft_planning_time"])
np.save(out, r.pressure)
print(json.dumps(dict(times=times, iterations=r.iterations, pairs=r.info["fft_pairs"],
                      singles=r.info["fft_pairs_single"],
                      increments=r.info.get("u_increments", 0))))
"""


def child(n, seed, tol, flag, repeats, out, name):
    res = subprocess.run([sys.executable, "-c", CHILD, str(n), str(seed), str(tol), "1" if flag else "0",
                          str(repeats), out, name, json.dumps(_lifted(name))], capture_output=True, text=True,
                         check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def _lifted(flag: str) -> dict:
    """Limits lifted so that the switch decides on every grid: ``FOLD_INCREMENT`` folds only up to
    ``FOLD_INCREMENT_MAX_NODES`` by default; its A/B compares the fold with the pass of its own at any size."""
    return {"FOLD_INCREMENT_MAX_NODES": 1 << 62} if flag == "FOLD_INCREMENT" else {}


def in_process(args) -> list:
    """The in-process rows: the switch flipped between alternating solves."""
    import gfmd_ref as g

    from bench_gfmd import solver_switches

    rows = []
    for seed in args.seeds:
        h, length = g.fig1_surface(args.n, seed=seed)
        kw = dict(length=length, E_star=E_STAR, mean_pressure=P0, interaction=g.HardWall(), tol=args.tol,
                  method="ccg")
        g.solve_contact(h, **kw)  # plans and compiled kernels
        times = {True: [], False: []}
        rest = {True: [], False: []}  # the solve less its transforms and multiplies (its own timers)
        ratios, rest_ratios, last = [], [], {}
        for k in range(args.rounds * args.repeats):
            for flag in ((True, False) if k % 2 == 0 else (False, True)):
                with solver_switches(**{args.flag: flag}, **_lifted(args.flag)):
                    last[flag] = r = g.solve_contact(h, **kw)
                times[flag].append(r.wall_time)
                rest[flag].append(r.wall_time - r.info["fft_planning_time"] - r.info["fft_seconds"]
                                  - r.info["multiply_seconds"])
            ratios.append(times[True][-1] / times[False][-1])
            rest_ratios.append(rest[True][-1] / rest[False][-1])
        dp = float(np.max(np.abs(last[True].pressure - last[False].pressure))) / P0
        q25, q50, q75 = np.quantile(ratios, [0.25, 0.5, 0.75])
        r25, r50, r75 = np.quantile(rest_ratios, [0.25, 0.5, 0.75])
        row = (f"| {seed} | {last[True].iterations} / {last[False].iterations} | {len(ratios)} | "
               f"{statistics.median(times[True]):.3f} | {statistics.median(times[False]):.3f} | "
               f"{statistics.median(times[True]) / statistics.median(times[False]):.3f} | "
               f"{q50:.3f} ({q25:.3f}-{q75:.3f}) | {statistics.median(rest[True]):.3f} / "
               f"{statistics.median(rest[False]):.3f} | {r50:.3f} ({r25:.3f}-{r75:.3f}) | {dp:.1e} |")
        print(row, flush=True)
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flag", default="INCREMENT_U32", choices=["INCREMENT_U32", "SINGLE_STEP", "SINGLE_PRECOND",
                                                                "INCREMENT_REUSE_R", "FOLD_INCREMENT"])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--in-process", action="store_true", help="flip the switch between solves in this process")
    args = ap.parse_args()
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    what = {"INCREMENT_U32": "`u` by single-precision increments against an exact `u` after every step",
            "SINGLE_STEP": "step length's pair in single precision against double",
            "SINGLE_PRECOND": "preconditioner's pair in single precision against double",
            "INCREMENT_REUSE_R": "the increment of a step that kept the contact set from `r = G t` against its own "
                                 "pair",
            "FOLD_INCREMENT": "the increment applied by the next gap pass against a pass of its own"}[args.flag]
    if args.in_process:
        lines = [f"# `ccg` {what} ({args.n}^2, Fig. 1 surface, tol {args.tol:g}; `{args.flag}` on / off, "
                 "one process)",
                 "", f"The switch flipped between alternating solves, {args.rounds * args.repeats} pairs per seed "
                 f"after a warm-up; load at the start {load}.", "",
                 "The rest: a solve's time less its transforms and multiplies, by its own timers "
                 "(`info[\"fft_seconds\"]`, `info[\"multiply_seconds\"]`): for a switch that changes no pair, its "
                 "pair ratio is free of the FFTs' drift.", "",
                 "| seed | iterations (on / off) | pairs | on median [s] | off median [s] | ratio of medians "
                 "| median pair ratio (q25-q75) | the rest, on / off median [s] | the rest's median pair ratio "
                 "(q25-q75) | max dp [p0] |", "|---|---|---|---|---|---|---|---|---|---|"]
        lines += in_process(args)
        out = HERE / "results" / f"gfmd_{args.flag.lower()}_{args.n}_inproc.md"
        out.write_text("\n".join(lines) + "\n")
        print(f"wrote {out}")
        return
    lines = [f"# `ccg` {what} ({args.n}^2, Fig. 1 surface, tol {args.tol:g}; `{args.flag}` on / off)", "",
             f"Fresh process per variant, alternating, {args.rounds} rounds, median of {args.repeats} warm solves per "
             f"process; load at the start {load}.", "",
             "| seed | iterations (on / off) | double pairs (on / off) | on [s] | off [s] | ratio of medians "
             "| per-round ratios | max dp [p0] |", "|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            a, b = [], []
            for k in range(args.rounds):
                first = k % 2 == 0  # alternate which variant runs first in a round
                for flag in ((True, False) if first else (False, True)):
                    got = child(args.n, seed, args.tol, flag, args.repeats, os.path.join(tmp, f"{int(flag)}.npy"),
                                args.flag)
                    (a if flag else b).append(got)
            ta = [statistics.median(x["times"]) for x in a]
            tb = [statistics.median(x["times"]) for x in b]
            dp = float(np.max(np.abs(np.load(os.path.join(tmp, "1.npy")) - np.load(os.path.join(tmp, "0.npy"))))) / P0
            ratios = ", ".join(f"{x / y:.2f}" for x, y in zip(ta, tb))
            doubles = [x["pairs"] - x["singles"] for x in (a[0], b[0])]
            row = (f"| {seed} | {a[0]['iterations']} / {b[0]['iterations']} | {doubles[0]} / {doubles[1]} | "
                   f"{', '.join(f'{x:.2f}' for x in ta)} | "
                   f"{', '.join(f'{x:.2f}' for x in tb)} | {statistics.median(ta) / statistics.median(tb):.3f} | "
                   f"{ratios} | {dp:.1e} |")
            print(row, flush=True)
            lines.append(row)
    out = HERE / "results" / f"gfmd_{args.flag.lower()}_{args.n}.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
