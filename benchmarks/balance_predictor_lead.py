"""How well is a balanced stage's multiplier predicted? The parabola against the cubic, and the previous level.

``local_g1_balanced`` on the Fig. 1 scene (48 shells), rtol 1e-6, integrated by the tests' Python oracle of the
compiled kernels (``tests/diffusion_pr/test_fv_kernels.py::_PythonKernels``: the kernels' algorithm in numpy and
LAPACK), with each balanced stage's first prediction of the multiplier ``A``, its root (Newton to 1e-15 p0 from
the same state) and the slope ``d<p>/dA`` recorded. A "first level" on ``n1`` coarsest cells and a "second" on
``n2`` (one grid family, ``n_cells`` fixed). Per second-level grid: the mean's miss over the balance's tolerance
(``1e-2 rtol p0``) of the kernel's own prediction, of the first level's ``4N``-grid root, and of the first level's
roots extrapolated in ``h^2``; medians over the stages and the share within the tolerance (a stage within it costs
one exponential). The forty-second session's output is ``results/balance_predictor_lead_s42.md`` (with the parabola
then in the kernel).

``--orders``: on each Fig. 1 closure problem as the solve builds it (its shells and grading, the second level's
coarsest cells), the kernel's prediction (the cubic through the last four ratios ``A/A_mid`` since the forty-second
session) against the parabola through the last three (before it), from the same recorded history of exact ratios
(``results/balance_predictor_order_s42.md``).

    python benchmarks/balance_predictor_lead.py [--orders]
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "diffusion_pr"))
import test_fv_kernels as T  # noqa: E402  (the oracle of the compiled kernels)

from diffusion_pr.closures import closure_problem, spectrum_shells  # noqa: E402
from diffusion_pr.solvers.fv import engine  # noqa: E402

from bench_fokker_planck import SPECTRUM  # noqa: E402

_ORACLE_STAGE = T._PythonKernels._balanced


class Recording(T._PythonKernels):
    """The oracle, recording per balanced stage ``(first prediction of A, its root, slope, tolerance)``."""

    def __init__(self) -> None:
        super().__init__()
        self.grids: list = []

    def run(self, *args, **kwargs):
        self.current = []
        out = super().run(*args, **kwargs)
        self.grids.append(self.current)
        return out

    def midpoint_and_correction(self, base, wband, cvec, y, dt, p0) -> tuple:
        """``(A_mid, corr)`` of a stage's first prediction, as the oracle's ``_balanced`` makes them (before it
        updates its history): the prediction is ``A_mid r - corr``."""
        l0y, lwy = T._matvec(base, y), T._matvec(wband, y)
        a = float(cvec @ l0y) / float(cvec @ lwy)
        u = y + (0.5 * dt) * (l0y - a * lwy)
        den_u = float(cvec @ T._matvec(wband, u))
        s_pred = self.kappa * (-dt * den_u)
        return float(cvec @ T._matvec(base, u)) / den_u, (float(cvec @ y) - p0) / s_pred if s_pred < 0.0 else 0.0

    def _balanced(self, base, wband, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter):
        wl, wd, wu = wband

        def at(a):
            return (base[0] - a * wl, base[1] - a * wd, base[2] - a * wu)

        # the kernel's first prediction, as _balanced makes it (before it updates its history)
        a_mid, corr = self.midpoint_and_correction(base, wband, cvec, y, dt, p0)
        a_pred = a_mid * self._predicted_ratio() - corr
        out = _ORACLE_STAGE(self, base, wband, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter)
        root, slope = a_pred, -1.0
        for _ in range(30):
            trial, dtrial = T._cram_d(at(root), wband, dt, y, self.pfd, self.order)
            err, slope = float(cvec @ trial) - p0, float(cvec @ dtrial)
            if abs(err) < 1e-15 * p0 or slope == 0.0 or not np.isfinite(err / slope):
                break
            root -= err / slope
        self.current.append((out[1], a_pred, root, slope, mean_tol * p0))
        return out


def stages(zeta: float, n_cells: int) -> list:
    """Per grid (N, 2N, 4N): the recorded stages of the ``n_cells`` solve."""
    problem = closure_problem(spectrum_shells(SPECTRUM, E_star=8 / 3, n_shells=48), zeta=zeta, E_star=8 / 3,
                              mean_pressure=0.004, closure="local_g1_balanced")
    kernels = Recording()
    engine._staged_kernels = lambda: kernels
    engine.solve_fv(problem, rtol=1e-6, backend="native", n_cells=n_cells, threads=1, p_floor=8.18e-19)
    return kernels.grids


class Orders(Recording):
    """The recording oracle with the parabola's prediction beside the kernel's, from the exact ratios
    ``(root + corr)/A_mid`` of the stages before."""

    def run(self, *args, **kwargs):
        self.exact = []
        return super().run(*args, **kwargs)

    def _balanced(self, base, wband, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter):
        a_mid, corr = self.midpoint_and_correction(base, wband, cvec, y, dt, p0)
        out = super()._balanced(base, wband, cvec, y, dt, m, p0, mean_tol, lin_tol, max_iter)
        _, a_pred, root, slope, tol = self.current[-1]
        r = self.exact
        parabola = None
        if len(r) >= 3:
            ratio = 3.0 * r[-1] - 3.0 * r[-2] + r[-3]
            parabola = a_mid * (ratio if 0.25 < ratio < 4.0 else r[-1]) - corr
        self.current[-1] += (abs((parabola - root) * slope) / tol if parabola is not None else None,)
        if a_mid != 0.0:
            r.append((root + corr) / a_mid)
        return out


def _closure_problem(zeta: float, closure: str) -> tuple:
    """``(problem, coarsest cells of its last level, p_floor)`` as ``pressure_distribution`` solves it."""
    import diffusion_pr as dp
    from diffusion_pr.solvers import native

    got = []
    solve_fv = native.solve_fv
    native.solve_fv = lambda problem, **kw: got.append((problem, kw)) or solve_fv(problem, **kw)
    try:
        res = dp.pressure_distribution(SPECTRUM, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure,
                                       rtol=1e-6)
    finally:
        native.solve_fv = solve_fv
    return got[0][0], int(res.diagnostics["levels"][0]), got[0][1].get("p_floor")


def orders() -> None:
    for closure in ("local_g1_balanced", "local_g1_shell_balanced"):
        for zeta in (4.0, 1.0, 0.25, 0.1, 0.01, 0.001):
            problem, n, p_floor = _closure_problem(zeta, closure)
            kernels = Orders()
            engine._staged_kernels = lambda: kernels
            engine.solve_fv(problem, rtol=1e-6, backend="native", n_cells=n, threads=1, p_floor=p_floor)
            grid = [s for s in kernels.grids[0] if s[5] is not None]  # (stages with four ratios before them)
            cubic = np.array([abs((s[1] - s[2]) * s[3]) / s[4] for s in grid])
            parabola = np.array([s[5] for s in grid])
            print(f"{closure:24s} zeta {zeta:6g} ({n} cells): miss/tol median parabola {np.median(parabola):8.2g} "
                  f"(within {np.mean(parabola <= 1):4.0%}), cubic {np.median(cubic):8.2g} "
                  f"(within {np.mean(cubic <= 1):4.0%}); exponentials {sum(s[0] for s in kernels.grids[0])} for "
                  f"{len(kernels.grids[0])} stages", flush=True)


def main() -> None:
    if "--orders" in sys.argv[1:]:
        orders()
        return
    for zeta, n1, n2 in ((0.01, 79, 632), (0.25, 79, 166), (1.0, 79, 169)):
        first, second = stages(zeta, n1), stages(zeta, n2)
        roots = [np.array([s[2] for s in grid]) for grid in first]
        extrapolated = (4.0 * roots[2] - roots[1]) / 3.0
        print(f"zeta {zeta}: L1 {n1} -> L2 {n2} cells")
        for g, grid in enumerate(second):
            def miss(a_of):
                return np.array([abs((a_of(k, s) - s[2]) * s[3]) / s[4] for k, s in enumerate(grid)])

            own, prev, extra = miss(lambda k, s: s[1]), miss(lambda k, s: roots[2][k]), \
                miss(lambda k, s: extrapolated[k])
            print(f"  L2 grid {g}: exps {sum(s[0] for s in grid)} for {len(grid)} stages; miss/tol median: "
                  f"current {np.median(own):.2g} (within tol {np.mean(own <= 1):.0%}), L1 4N's A {np.median(prev):.2g} "
                  f"({np.mean(prev <= 1):.0%}), L1 extrapolated A* {np.median(extra):.2g} ({np.mean(extra <= 1):.0%})")


if __name__ == "__main__":
    main()
