"""Richardson beyond fourth order: what a second extrapolation would buy (issue 10, closures at 10 ms).

Four nested grids ``M, N = 2M, 2N, 4N`` of the engine's grid family (rtol 1e-6 domain).  Printed, as L1
errors (cell masses, the cells below the floor lumped into the zero weight, as the engine reports them)
against the engine at 1024 coarse cells on the same domain (error below 1e-9):

* ``R(2N,4N)`` on the ``2N`` grid with its estimate ``|R(2N,4N) - R(N,2N)|/7``: what the engine returns today
  from the three grids ``N, 2N, 4N``;
* ``R2 = (16 R(2N,4N) - R(N,2N))/15`` on the ``N`` grid (sixth order) with the estimate
  ``|R2 - R2(M, N, 2N)|/63`` that the fourth grid ``M`` makes possible;
* ``R2`` carried to the ``4N`` grid: the ``4N`` solution plus the correction ``R2 - y_4N`` prolongated by a
  cubic spline of its cumulative (one spline per knot segment, as ``PressureDistribution.cdf``).

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


def _prolong(corr: np.ndarray, coarse: np.ndarray, fine: np.ndarray, knots) -> np.ndarray:
    """Cell masses ``corr`` on ``coarse`` spread over the cells of ``fine`` (cubic spline of the cumulative)."""
    from scipy.interpolate import CubicSpline

    cum = np.concatenate(([0.0], np.cumsum(corr)))
    out = np.empty(fine.size)
    inner = [k for k in knots if coarse[0] < k < coarse[-1]]
    cuts = [0, *sorted(set(int(j) for j in np.searchsorted(coarse, inner))), coarse.size - 1]
    for a, b in zip(cuts[:-1], cuts[1:]):
        sel = (fine >= coarse[a]) & (fine <= coarse[b])
        seg = CubicSpline(coarse[a:b + 1], cum[a:b + 1]) if b - a >= 2 else None
        out[sel] = seg(fine[sel]) if seg is not None else np.interp(fine[sel], coarse[a:b + 1], cum[a:b + 1])
    return np.diff(out)


def rows(problem, sizes=(24, 32, 48, 64)):
    ref = engine.solve_fv(problem, rtol=1e-6, backend="native", n_cells=1024)
    prep = engine.prepare(problem, rtol=1e-6)
    agg = engine._aggregate

    def l1(y, e):
        j = int(np.searchsorted(e, prep.lump_below)) if prep.lump_below > 0 else 0
        y, e = engine._lump(y, j), e[j:]
        return float(np.sum(np.abs(np.diff(ref.cdf(e)) - y[1:])) + abs(y[0] - ref.zero_weight))

    for m in sizes:
        idx = grid.knot_indices(prep.spec, m)
        finest = grid.edges_for(prep.spec, idx, 8)
        es = [finest[::8], finest[::4], finest[::2], finest]
        ys = [engine.solve_on_grid(prep, e, n_base=int(idx[-1]), refine=2 ** k, mean_tol=1e-12)[0]
              for k, e in enumerate(es)]
        r1 = [(4 * agg(ys[k + 1]) - ys[k]) / 3 for k in range(3)]
        r2_coarse, r2 = (16 * agg(r1[1]) - r1[0]) / 15, (16 * agg(r1[2]) - r1[1]) / 15
        carried = np.concatenate(([r2[0]], ys[3][1:] + _prolong((r2 - agg(agg(ys[3])))[1:], es[1], es[3],
                                                                prep.spec.knots)))
        yield (es[1].size - 1, l1(r1[2], es[2]), float(np.abs(agg(r1[2]) - r1[1]).sum()) / 7,
               l1(r2, es[1]), float(np.abs(agg(r2) - r2_coarse).sum()) / 63, l1(carried, es[3]),
               sum(e.size - 1 for e in es))


def main() -> None:
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    cases = {name: problems()[name][0] for name in ("fig1-z0.25", "fig1-z1")}
    cases["local_g1 zeta 0.25"] = closure_problem(spectrum_shells(spec, E_star=8 / 3), zeta=0.25, E_star=8 / 3,
                                                  mean_pressure=0.004, closure="local_g1")
    print("| problem | N | today: R(2N,4N) on 2N cells, error (estimate) | R2 on N cells, error (estimate) | "
          "R2 carried to 4N cells, error | cells of M..4N (today: 7N) |")
    print("|---|---|---|---|---|---|")
    for name, prob in cases.items():
        for n, e1, est1, e2, est2, ec, cells in rows(prob):
            print(f"| {name} | {n} | {e1:.1e} ({est1:.1e}) | {e2:.1e} ({est2:.1e}) | {ec:.1e} | {cells} ({7 * n}) |",
                  flush=True)


if __name__ == "__main__":
    main()
