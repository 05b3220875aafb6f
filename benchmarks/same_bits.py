"""Do two versions of the package give the same answers, bit for bit?  A check for changes meant to be speed only.

``save`` solves 66 problems and writes their answers (edges, densities, zero weights, estimates, success) to a
file; ``check`` solves them again with the code as it is now and lists the ones whose bits differ, and the largest
L1 change of the cell masses among them (so that a change of round-off can be told from a change of answer):

    python benchmarks/same_bits.py save /tmp/base.pkl      # before the change
    python benchmarks/same_bits.py check /tmp/base.pkl     # after it

The problems: the mirror Gaussian (two scales), Feller's solution and the Fig. 1 scenes (``zeta`` 4, 1, 0.25,
0.01) with Muser's and the smoothstep cutoff, each by native at rtol 1e-4, 1e-6 and 1e-8, by py-pde's operator and
with the sixth-order extrapolation at 1e-6; the three shell closures at ``zeta`` 0.01, 0.25 and 4; a 12-``zeta``
sweep by ``pressure_distributions``; a constant drift.  About 5 s.
"""
from __future__ import annotations

import argparse
import pickle

import numpy as np

import diffusion_pr as dp
from diffusion_pr.problem import FokkerPlanckProblem
from diffusion_pr.solvers import get_backend

from bench_fokker_planck import SPECTRUM  # the Fig. 1 spectrum of the other benchmarks


def cases() -> dict:
    """``key -> solve()``: the problems, each a call returning a result or a list of results."""
    native, pypde = get_backend("native"), get_backend("pypde")
    problems = {"mirror": FokkerPlanckProblem(1.0, 1.0), "mirror-small": FokkerPlanckProblem(0.01, 4e-4),
                "feller": FokkerPlanckProblem(1.0, 1.0, dp.ProportionalDiffusivity(1.0))}
    for zeta, p_c in {4.0: 0.0027, 1.0: 0.0027, 0.25: 0.0027, 0.01: 0.0082}.items():
        V = float(dp.stress_variance(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta))
        for name, cutoff in (("fig1", dp.MuserCutoff(p_c)), ("smooth", dp.SmoothstepCutoff(p_c))):
            problems[f"{name}-{zeta:g}"] = FokkerPlanckProblem(0.004, V, dp.PressureFactor(cutoff, dp.GaussianTail()))
    out = {}
    for name, pr in problems.items():
        for rtol in (1e-4, 1e-6, 1e-8):
            out[(name, "native", rtol)] = lambda pr=pr, rtol=rtol: native(pr, rtol=rtol)
        out[(name, "pypde", 1e-6)] = lambda pr=pr: pypde(pr, rtol=1e-6)
        out[(name, "sixth", 1e-6)] = lambda pr=pr: native(pr, rtol=1e-6, extrapolation="sixth")
    for closure in ("local_g1", "local_g1_balanced", "local_g1_shell_balanced"):
        for zeta in (0.01, 0.25, 4.0):
            out[(closure, zeta)] = lambda closure=closure, zeta=zeta: dp.pressure_distribution(
                SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure, rtol=1e-6)
    out[("sweep",)] = lambda: dp.pressure_distributions(SPECTRUM, zetas=np.geomspace(1e-3, 4.0, 12), E_star=8 / 3,
                                                        mean_pressure=0.004, cutoff="muser", p_c=0.0027, rtol=1e-6)
    out[("drift",)] = lambda: native(FokkerPlanckProblem(1.0, 1.0, drift=lambda p, tau: 0.3 + 0.0 * p), rtol=1e-6)
    return out


def answers() -> dict:
    """``key -> [(edges, density, zero weight, estimate, success), ...]`` (or the exception's repr)."""
    out = {}
    for key, solve in cases().items():
        try:
            res = solve()
        except Exception as exc:  # a failure is an answer too: it must stay the same
            out[key] = repr(exc)
            continue
        out[key] = [(np.asarray(r.edges).copy(), np.asarray(r.density).copy(), float(r.zero_weight),
                     float(r.error_estimate), bool(r.success)) for r in (res if isinstance(res, list) else [res])]
    return out


def _same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return len(a) == len(b) and all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) and x[2:] == y[2:]
                                    for x, y in zip(a, b))


def _l1(a, b) -> float:
    """The largest L1 change of the cell masses and zero weight (inf where a grid or a failure changed)."""
    if isinstance(a, str) or isinstance(b, str) or len(a) != len(b):
        return float("inf")
    worst = 0.0
    for x, y in zip(a, b):
        if x[0].shape != y[0].shape:
            return float("inf")
        worst = max(worst, float(np.sum(np.abs(x[1] * np.diff(x[0]) - y[1] * np.diff(y[0])))) + abs(x[2] - y[2]))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("save", "check"))
    ap.add_argument("path", help="the file of the saved answers")
    args = ap.parse_args()
    now = answers()
    if args.mode == "save":
        with open(args.path, "wb") as fh:
            pickle.dump(now, fh)
        print(f"saved {len(now)} answers to {args.path}")
        return
    with open(args.path, "rb") as fh:
        base = pickle.load(fh)
    differ = [k for k in base if not _same(base[k], now.get(k, "missing"))]
    print(f"{len(base)} answers, {len(base) - len(differ)} the same bits")
    for k in differ:
        print(f"  differs: {k}  (largest L1 change {_l1(base[k], now.get(k, 'missing')):.2e})")


if __name__ == "__main__":
    main()
