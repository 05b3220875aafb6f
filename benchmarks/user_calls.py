"""The user-visible calls, timed side by side on one or more source trees.

Each group of calls runs in a fresh subprocess with ``PYTHONPATH=<tree>``; the trees alternate within every round
(A B, then B A, ...), and the table gives per call the median over the rounds of each process's median, per
tree, and the ratio of the last tree over the first (after / before).  Only public calls are used, so that two
versions of the package can be compared:

* ``gfmd``: ``gfmd_ref.solve_contact`` on ``fig1_surface(n, seed=1)``, hard wall, tol 1e-8, at 1024^2 and 2048^2
  (after a loose solve that compiles the kernels and plans the FFTs);
* ``fp``: native Fokker-Planck (rtol 1e-6) on the mirror Gaussian (``f = 1`` for ``p > 0`` as a user writes it)
  and on the Fig. 1 second-order scenes (``pressure_distribution`` with Muser's cutoff at the paper's ``p_c``);
* ``closures``: ``local_g1``, ``local_g1_balanced``, ``local_g1_shell_balanced`` on the Fig. 1 spectrum
  (``E* = 8/3``, ``p0 = 0.004``, rtol 1e-6) at zeta 4, 1, 0.25, 0.1, 0.01, 0.001;
* ``fig1``: the main job, ``python -m diffusion_pr.cli fig1 --out <tmpdir>`` (default n = 512), its process's
  wall time;
* ``first``: the first closure result in a fresh process, numba's cache warm (``cold_start.py``).

    python benchmarks/user_calls.py --tree /path/before --tree /path/after [--quick]

Without ``--tree`` the tree this script belongs to is timed alone.  ``--quick``: one round of the heavy groups
(GFMD 2048^2, fig1), fewer repeats elsewhere (about 5 minutes for two trees on a loaded 2-core machine).
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import HERE, fmt, section, table

CHILD = r"""
import json, sys, time, warnings
import numpy as np
group, repeats = sys.argv[1], int(sys.argv[2])
calls = {}
if group.startswith("gfmd"):
    import gfmd_ref as g
    n = int(group.split()[1])
    h, L = g.fig1_surface(n, seed=1)
    def hard(tol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return g.solve_contact(h, length=L, E_star=8 / 3, mean_pressure=0.004, interaction=g.HardWall(), tol=tol)
    hard(1e-2)  # compile, plan the FFTs
    calls[f"GFMD hard wall {n}^2, tol 1e-8"] = lambda: hard(1e-8)
else:
    import diffusion_pr as dp
    S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    if group == "fp":
        calls["native FP, mirror Gaussian"] = lambda: dp.propagate(
            1.0, 1.0, diffusivity=lambda p: np.where(p > 0, 1.0, 0.0), backend="native", rtol=1e-6)
        for zeta, pc in ((4.0, 0.0027), (1.0, 0.0027), (0.25, 0.0027), (0.01, 0.0082)):
            calls[f"native FP, Fig. 1 scene zeta {zeta:g}"] = (lambda zeta=zeta, pc=pc: dp.pressure_distribution(
                S, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, cutoff="muser", p_c=pc, backend="native", rtol=1e-6))
    else:
        for closure in ("local_g1", "local_g1_balanced", "local_g1_shell_balanced"):
            for zeta in (4.0, 1.0, 0.25, 0.1, 0.01, 0.001):
                calls[f"{closure}, zeta {zeta:g}"] = (lambda closure=closure, zeta=zeta: dp.pressure_distribution(
                    S, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure, rtol=1e-6))
out, times, last = {}, {label: [] for label in calls}, {}
for label, call in list(calls.items()):
    try:
        if not group.startswith("gfmd"):
            call()  # warm
    except Exception as exc:  # a call this version does not have: reported, not timed
        out[label] = dict(seconds=None, success=False, error=f"{type(exc).__name__}: {exc}"[:120])
        del calls[label]
for _ in range(repeats):  # the calls interleaved: a burst of load on the machine hits them all
    for label, call in calls.items():
        t0 = time.perf_counter()
        last[label] = call()
        times[label].append(time.perf_counter() - t0)
for label in calls:
    r = last[label]
    ok = bool(getattr(r, "success", getattr(r, "converged", True)))
    out[label] = dict(seconds=sorted(times[label])[len(times[label]) // 2], success=ok)
print(json.dumps(out))
"""
#: group -> (rounds, repeats in one process), full and quick
GROUPS = {"gfmd 1024": ((3, 1), (1, 1)), "gfmd 2048": ((3, 1), (1, 1)), "fp": ((5, 31), (3, 15)),
          "closures": ((5, 11), (3, 7)), "fig1": ((3, 1), (1, 1)), "first": ((5, 1), (3, 1))}


def seconds(x) -> str:
    """A time for the table: milliseconds below a second."""
    return "-" if x is None else f"{1e3 * x:.2f} ms" if x < 1.0 else f"{x:.2f} s"


def run_group(tree: Path, group: str, repeats: int) -> dict:
    """``label -> dict(seconds, success[, error])`` of one group in one fresh process on ``tree``."""
    from cold_start import child_env, first_result

    env = child_env(tree)
    if group == "first":
        try:
            r = first_result(tree)
            return {"first closure result, fresh process (warm cache)": dict(seconds=r["first_s"],
                                                                             success=r["success"])}
        except RuntimeError as exc:
            return {"first closure result, fresh process (warm cache)": dict(seconds=None, success=False,
                                                                             error=str(exc)[:120])}
    if group == "fig1":
        out = tempfile.mkdtemp(prefix="user_calls_fig1_")
        try:
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "diffusion_pr.cli", "fig1", "--out", out],
                                  capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
            wall = time.perf_counter() - t0
        finally:
            shutil.rmtree(out, ignore_errors=True)
        return {"`diffusion-pr fig1` (n = 512), whole process": dict(
            seconds=wall if proc.returncode == 0 else None, success=proc.returncode == 0,
            **({} if proc.returncode == 0 else {"error": proc.stderr.strip()[-120:]}))}
    proc = subprocess.run([sys.executable, "-c", CHILD, group, str(repeats)], capture_output=True, text=True,
                          env=env, cwd=tempfile.gettempdir())
    if proc.returncode != 0:
        return {f"{group} (the whole group)": dict(seconds=None, success=False, error=proc.stderr.strip()[-120:])}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compare(trees: list, quick: bool, groups=tuple(GROUPS)) -> tuple:
    """``(labels, {tree: {label: [seconds per round]}}, {tree: {label: success}}, errors)``."""
    times = {t: {} for t in trees}
    success = {t: {} for t in trees}
    errors = []
    labels: list = []
    for group in groups:
        rounds, repeats = GROUPS[group][1 if quick else 0]
        for k in range(rounds):
            for tree in (trees if k % 2 == 0 else trees[::-1]):
                t0 = time.perf_counter()
                res = run_group(tree, group, repeats)
                print(f"{group}, round {k + 1}/{rounds}, {tree}: {time.perf_counter() - t0:.1f} s", flush=True)
                for label, r in res.items():
                    if label not in labels:
                        labels.append(label)
                    if r["seconds"] is not None:
                        times[tree].setdefault(label, []).append(r["seconds"])
                    success[tree][label] = success[tree].get(label, True) and r["success"]
                    if r.get("error"):
                        errors.append(f"{tree}: {label}: {r['error']}")
    return labels, times, success, sorted(set(errors))


def run(quick: bool = False, trees=None) -> str:
    trees = [Path(t).resolve() for t in (trees or [HERE.parent])]
    labels, times, success, errors = compare(trees, quick)
    names = [str(t) for t in trees]
    header = ["call"] + names + (["after / before"] if len(trees) > 1 else [])
    rows = []
    for label in labels:
        med = [statistics.median(times[t][label]) if times[t].get(label) else None for t in trees]
        cells = [seconds(m) + ("" if success[t].get(label, False) else " (failed)") for m, t in zip(med, trees)]
        ratio = [fmt(med[-1] / med[0] if med[0] and med[-1] else None, ".2f")] if len(trees) > 1 else []
        rows.append([label] + cells + ratio)
    return section("User-visible calls" + (" side by side" if len(trees) > 1 else ""), table(header, rows),
                   "Medians over rounds (one fresh process per group, tree and round; trees alternating) of each "
                   "process's median over its repeats (the calls of a group interleaved); GFMD, fig1 and the first "
                   "result one call per process."
                   + (" Quick run: one round of the heavy groups." if quick else ""),
                   ("Calls that failed: " + "; ".join(errors)) if errors else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", action="append", default=None,
                    help="a source tree (run with PYTHONPATH=TREE); repeat it: the first is 'before', the last "
                         "'after' (default: this script's tree alone)")
    ap.add_argument("--quick", action="store_true", help="fewer rounds and repeats (about 5 minutes for two trees)")
    args = ap.parse_args()
    run(args.quick, args.tree)


if __name__ == "__main__":
    main()
