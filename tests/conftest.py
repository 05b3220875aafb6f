"""Shared pytest fixtures."""
from __future__ import annotations

import numpy as np
import pytest


def _l1_on_cells(answer, ref) -> float:
    """L1 distance of ``answer``'s non-contact weight and cell masses from ``ref``'s on ``answer``'s cells (through
    each distribution's cdf, so the two grids need not be the same)."""
    x = np.concatenate(([0.0], answer.edges))
    return float(abs(answer.zero_weight - ref.zero_weight)
                 + np.sum(np.abs(np.diff(answer.cdf(x))[1:] - np.diff(ref.cdf(x))[1:])))


@pytest.fixture
def l1_on_cells():
    """``l1_on_cells(answer, ref)``: the L1 distance of two pressure distributions on ``answer``'s cells, the
    non-contact weight included."""
    return _l1_on_cells


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded random generator: every test that draws numbers is reproducible."""
    return np.random.default_rng(20080205)


@pytest.fixture
def closure_like_problem():
    """Factory of a staged problem shaped like the load-balanced local-G1 closure
    (docs/closures.md): ``f = g^2 ~ p^2`` at 0, drift ``(1 - g_min) g^2 / p`` and
    balance ``(1 - g_min) p`` vanishing at 0; ``n_stages`` shells, mean ``0.004``."""
    from diffusion_pr.problem import Stage, StagedProblem

    def make(n_stages: int = 12, mean_pressure: float = 0.004) -> StagedProblem:
        stages = []
        g_min = lambda p: p / (p + 0.002)  # noqa: E731
        for q in np.geomspace(1.0, 30.0, n_stages):
            g = (lambda p, c=0.002 * q: p / (p + c))
            stages.append(Stage(4.5e-4 / n_stages, lambda p, g=g: g(p) ** 2,
                                drift=lambda p, g=g: (1 - g_min(p)) * g(p) ** 2 / np.maximum(p, 1e-300),
                                balance=lambda p: (1 - g_min(p)) * p))
        return StagedProblem(mean_pressure, tuple(stages))

    return make
