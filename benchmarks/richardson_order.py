"""Richardson beyond fourth order: how much a second extrapolation would buy (issue 10, closures at 10 ms).

The engine returns ``R(2N,4N) = (4 y_4N - y_2N)/3`` (fourth order) on three nested grids.  This script
integrates five nested grids ``n, 2n, ..., 16n`` and prints, against the most extrapolated value, the L1
error (cell masses on the ``n`` grid) of the once extrapolated ``R1`` (what the engine returns), the twice
extrapolated ``R2 = (16 R1' - R1)/15`` and their observed orders.  A second extrapolation on the same three
grids is worth 20-60x in error at the cells the engine uses; using it needs a fourth grid for an honest
estimate and an output on a grid as fine as today's (the cdf between edges), see docs/backends.md.

    python benchmarks/richardson_order.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diffusion_pr as dp  # noqa: E402
from bench_fokker_planck import problems  # noqa: E402
from diffusion_pr.closures import closure_problem, spectrum_shells  # noqa: E402
from diffusion_pr.solvers.fv import engine, grid  # noqa: E402


def errors(problem, n: int, levels: int = 5) -> tuple:
    """L1 errors (on the n grid) of R1 on grids (n, 2n, 4n) / (2n, 4n, 8n) and R2 on (n..4n) / (2n..8n)."""
    prep = engine.prepare(problem, rtol=1e-6)
    idx = grid.knot_indices(prep.spec, n)
    finest = grid.edges_for(prep.spec, idx, 2 ** (levels - 1))
    ys = []
    for k in range(levels):
        y, _ = engine.solve_on_grid(prep, finest[::2 ** (levels - 1 - k)], n_base=int(idx[-1]), refine=2 ** k,
                                    mean_tol=1e-12)
        for _ in range(k):
            y = engine._aggregate(y)
        ys.append(y)
    r1 = [(4 * ys[k + 1] - ys[k]) / 3 for k in range(levels - 1)]
    r2 = [(16 * r1[k + 1] - r1[k]) / 15 for k in range(levels - 2)]
    r3 = [(64 * r2[k + 1] - r2[k]) / 63 for k in range(levels - 3)]
    best = r3[-1]
    e = lambda v: float(np.sum(np.abs(v - best)))  # noqa: E731
    return e(r1[1]), e(r2[0]), e(r2[1])


def main() -> None:
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    cases = {name: problems()[name][0] for name in ("mirror", "fig1-z0.25", "fig1-z1")}
    cases["local_g1 zeta 0.25"] = closure_problem(spectrum_shells(spec, E_star=8 / 3), zeta=0.25, E_star=8 / 3,
                                                  mean_pressure=0.004, closure="local_g1")
    print("| problem | n | R1 on (n, 2n, 4n): the engine's answer | R2 on (n, 2n, 4n) | R2 on (2n, 4n, 8n) |")
    print("|---|---|---|---|---|")
    for name, prob in cases.items():
        for n in (24, 48, 96):
            e1, e2a, e2b = errors(prob, n)
            print(f"| {name} | {n} | {e1:.1e} | {e2a:.1e} | {e2b:.1e} |", flush=True)


if __name__ == "__main__":
    main()
