"""Shared pytest fixtures."""
from __future__ import annotations

import numpy as np
import pytest


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
