"""A balanced closure's fixed-shell problem by the compact scheme end to end, against the engine (issue 10).

The earlier scripts measured the compact scheme on the prototype's own problem. This one takes the engine's:
the Fig. 1 scene's closure as a :class:`~diffusion_pr.problem.StagedProblem` (``closure_problem`` on
``spectrum_shells(..., n_shells=48)``: no shell extrapolation, so both solvers answer the same question), and
solves it with the package's compact parts (:mod:`diffusion_pr.solvers.fv.compact`):

* nodes uniform in ``xi(p) = p / w + lam ln(p / p_floor)`` (``w = p0/4``; logarithmic in the deep layer, linear
  above), the spacing fixed by ``[p_floor, p0]`` so that the floor and ``p0`` are nodes exactly and the spacing is
  the same on both sides of ``p0``; the top node the first at or above the engine's ``p_max`` (closed there);
* the engine's own domain: its absorbing bottom ``BOTTOM_EFOLDS_DRIFT`` (ln 1e7) e-folds below its floor, where a
  problem with drift puts it, the floor itself not a node (the answer is compared at the nodes above it);
* the coefficient rows of all stages in one compiled pass (the closures' ``rows``), ``f_p`` in closed form;
* ``corrected_delta_start``, then :func:`run_stages` (CRAM-16, balance to ``1e-8 p0`` as the engine at rtol 1e-6)
  on three nested grids ``N, 2N, 4N``; the answer ``R4 = (16 X(2N) - X(N))/15`` at the ``N`` grid's nodes from
  the two finer grids, its estimate ``max |R4(2N, 4N) - R4(N, 2N)|`` at the ``N`` grid's nodes.

The reference is the engine at rtol 1e-9 on the same problem. Errors are the largest difference of the
cumulative distribution, zero weight included, at the compact answer's nodes above the floor (the reference's ``cdf``: exact at its
edges, fourth order between), i.e. a Kolmogorov distance. The engine at rtol 1e-6 is measured the same way, and
both are timed in the same process (medians).

    python benchmarks/compact_closure.py [--zetas 0.1 0.01] [--n0 40 80]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_variance import median_time  # noqa: E402
import diffusion_pr as dp  # noqa: E402
from bench_fokker_planck import SPECTRUM  # noqa: E402
from diffusion_pr.closures import (LoadExcessDrift, LocalResponseDiffusivity, RigidApproachBalance,  # noqa: E402
                                   closure_problem, spectrum_shells)
from diffusion_pr.solvers.fv.compact import (corrected_delta_start, mean_weights, run_stages,  # noqa: E402
                                             stage_rows)
from diffusion_pr.closures import BALANCED_FLOOR  # noqa: E402
from diffusion_pr.solvers.fv.engine import prepare  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "compact_closure.md"
E_STAR, P0, SHELLS = 8.0 / 3.0, 0.004, 48
MEAN_TOL = 1e-8  # the engine's at rtol 1e-6 (MEAN_TOL_FRACTION * rtol)
LIN_TOL = 1e-4


def prototype_monitor(p_bottom: float, p_max: float, p0: float):
    """``xi(p) = p / w + lam ln(p / p_bottom)`` (``w = p0/4``, ``lam`` giving the linear and logarithmic parts equal
    shares): ``fourth_order_space.py``'s family."""
    w = 0.25 * p0
    lam = (p_max / w) / math.log(p_max / p_bottom)
    return lambda p: p / w + lam * np.log(p / p_bottom)


def nodes(monitor, p_bottom: float, p_max: float, p0: float, n_below: int, refine: int = 1) -> np.ndarray:
    """Nodes uniform in the increasing ``monitor(p)``: ``n_below`` intervals on ``[p_bottom, p0]`` (both nodes
    exactly), the same spacing above up to the first node at or above ``p_max``; each interval split in ``refine``
    (nested grids: the same ends). Inverted by bisection to round-off (robust for any increasing monitor)."""
    x_b, x0, x_top = (float(monitor(np.array(v))) for v in (p_bottom, p0, p_max))
    dx = (x0 - x_b) / n_below
    n_above = int(math.ceil((x_top - x0) / dx))
    targets = x0 + dx / refine * np.arange(-n_below * refine, n_above * refine + 1)
    lo = np.full(targets.shape, math.log(p_bottom))
    hi = np.full(targets.shape, math.log(p_max) + 5.0)
    for _ in range(200):  # bisection in ln p
        mid = 0.5 * (lo + hi)
        below = monitor(np.exp(mid)) < targets
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
        if np.max(hi - lo) < 1e-15:
            break
    p = np.exp(0.5 * (lo + hi))
    p[0], p[n_below * refine] = p_bottom, p0
    return p


def rows_of(problem, p: np.ndarray) -> tuple:
    """``stage_rows`` of every stage of a balanced closure's problem at the nodes ``p``."""
    stages = problem.stages
    f_models = tuple(s.diffusivity for s in stages)
    f = LocalResponseDiffusivity.rows(f_models, p)
    kq = np.array([m.kz * m.q for m in f_models])[:, None]
    g = p / (p + kq)
    f_p = 2.0 * g * kq / (p + kq) ** 2
    b = LoadExcessDrift.rows(tuple(s.drift for s in stages), p)
    w = RigidApproachBalance.rows(tuple(s.balance for s in stages), p)
    return stage_rows(p, f, f_p, b, w)


def compact_solve(problem, monitor, p_bottom: float, p_max: float, n_below: int) -> dict:
    """The compact answer on three nested grids (``n_below``, 2x, 4x intervals below ``p0``) of ``monitor``'s
    family on ``[p_bottom, p_max]``."""
    t0 = time.perf_counter()
    durations = np.array([s.duration for s in problem.stages])
    runs = []
    for k in (1, 2, 4):
        p = nodes(monitor, p_bottom, p_max, P0, n_below, k)
        M, _, info = run_stages(rows_of(problem, p), durations, corrected_delta_start(p.size, n_below * k),
                                weights=mean_weights(p), p0=P0, mean_tol=MEAN_TOL, lin_tol=LIN_TOL)
        runs.append((p, M, info))
    (p1, m1, _), (p2, m2, _), (p4, m4, _) = runs
    r_coarse = (16.0 * m2[::2] - m1) / 15.0
    r_fine = (16.0 * m4[::2] - m2) / 15.0
    estimate = float(np.max(np.abs(r_fine[::2] - r_coarse)))
    return {"p": p2, "M": r_fine, "p_coarse": p1, "estimate": estimate, "seconds": time.perf_counter() - t0,
            "cells": (p1.size - 1, p2.size - 1, p4.size - 1), "info": [r[2] for r in runs]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.1, 0.01])
    ap.add_argument("--closures", nargs="+", default=["local_g1_balanced", "local_g1_shell_balanced"])
    ap.add_argument("--n0", type=int, nargs="+", default=[40, 80, 160],
                    help="intervals below p0 on the coarsest grid")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    lines = ["# A balanced closure's fixed-shell problem, compact against the engine "
             "(`python benchmarks/compact_closure.py`)", "",
             f"Fig. 1 scene, {SHELLS} shells (`spectrum_shells`, no shell extrapolation), the closures' own floor "
             "(`BALANCED_FLOOR` q_min zeta E*/2) and the engine's domain (its bottom ln 1e7 below the floor, its "
             "p_max). Reference: the engine at rtol 1e-9. Errors at the nodes above the floor of each answer's own "
             "grid (the answer's: the 2N grid of each, the engine's lumped below the floor): `L1`, the sum of "
             "|cell mass - reference's| (zero weight included); `K`, the largest CDF "
             "difference. Estimates: the compact one max |R4(2N,4N) - R4(N,2N)| of the CDF; the engine's its L1 "
             f"estimate. Times: medians of {args.repeats} warm calls in the same process.", "",
             "| closure | zeta | solver | family | cells: the last level's three grids | L1 | K | estimate | time [ms] |",
             "|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for closure in args.closures:
        for zeta in args.zetas:
            shells = spectrum_shells(SPECTRUM, E_star=E_STAR, n_shells=SHELLS)
            problem = closure_problem(shells, zeta=zeta, E_star=E_STAR, mean_pressure=P0, closure=closure)
            p_floor = BALANCED_FLOOR * 0.5 * zeta * E_STAR * shells.q_min
            ref = dp.solve_problem(problem, backend="native", rtol=1e-9, p_floor=p_floor)
            spec = prepare(problem, rtol=1e-6, p_floor=p_floor).spec
            p_bottom, p_max = spec.p_wall, float(ref.diagnostics["p_max"])

            def errors(p: np.ndarray, cdf: np.ndarray) -> tuple:
                above = p >= p_floor
                d = cdf[above] - ref.cdf(p[above])
                return float(abs(d[0]) + np.sum(np.abs(np.diff(d)))), float(np.max(np.abs(d)))

            eng = dp.solve_problem(problem, backend="native", rtol=1e-6, p_floor=p_floor)
            t_eng = median_time(lambda: dp.solve_problem(problem, backend="native", rtol=1e-6, p_floor=p_floor),
                                args.repeats)
            l1, k = errors(eng.edges, eng.cdf(eng.edges))
            lines.append(f"| `{closure}` | {zeta:g} | engine, rtol 1e-6 | its own | "
                         f"{'/'.join(map(str, eng.diagnostics['levels']))} (answer {eng.diagnostics['n_cells']} above "
                         "the floor) | "
                         f"{l1:.1e} | {k:.1e} | {eng.error_estimate:.1e} (L1) | {t_eng * 1e3:.1f} |")
            print(lines[-1], flush=True)
            for family, monitor in (("engine's", lambda p: spec.phi(p)),
                                    ("prototype's", prototype_monitor(p_bottom, p_max, P0))):
                for n0 in args.n0:
                    try:
                        res = compact_solve(problem, monitor, p_bottom, p_max, n0)
                    except RuntimeError as exc:
                        lines.append(f"| `{closure}` | {zeta:g} | compact, {n0} below p0 | {family} | | "
                                     f"{str(exc)[:60]} | | | |")
                        print(lines[-1], flush=True)
                        continue
                    t_c = median_time(lambda: compact_solve(problem, monitor, p_bottom, p_max, n0), args.repeats)
                    l1, k = errors(res["p"], res["M"])
                    lines.append(f"| `{closure}` | {zeta:g} | compact, {n0} below p0 | {family} | "
                                 f"{'/'.join(map(str, res['cells']))} | {l1:.1e} | {k:.1e} | {res['estimate']:.1e} | "
                                 f"{t_c * 1e3:.1f} |")
                    print(lines[-1], flush=True)
            lines.append(f"| | | (reference: {ref.diagnostics['n_cells']} cells, zero weight {ref.zero_weight:.4f}, "
                         f"p_floor {p_floor:.2e}, domain bottom {p_bottom:.2e}, p_max {p_max:.3g}) | | | | | | |")
            print(lines[-1], flush=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
