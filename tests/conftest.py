"""Shared pytest fixtures."""
from __future__ import annotations


import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

# the test oracles (tests/oracles, e.g. the closures' reference solver) import as ``oracles.*``; registered as a
# package of its own, since putting tests/ on sys.path would shadow the installed diffusion_pr and gfmd_ref with
# the namespace packages tests/diffusion_pr and tests/gfmd_ref
_ORACLES = Path(__file__).resolve().parent / "oracles"
_spec = importlib.util.spec_from_file_location("oracles", _ORACLES / "__init__.py",
                                               submodule_search_locations=[str(_ORACLES)])
if "oracles" not in sys.modules:
    sys.modules["oracles"] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules["oracles"])


def pytest_report_header(config) -> str:
    """The numerical stack's versions and the CPU on the report's first lines: answers that follow a branch decided
    at round-off (a regrade, a balance retry; tests/diffusion_pr/test_fv_kernels.py) and constants recomputed by
    another LAPACK can change with them, so a failing run says which ones it had."""
    import importlib.metadata as md
    import platform

    names = ("numpy", "scipy", "numba", "py-pde", "fipy", "pyfftw", "dask")
    versions = []
    for name in names:
        try:
            versions.append(f"{name} {md.version(name)}")
        except md.PackageNotFoundError:
            versions.append(f"{name} -")
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), cpu)
    except OSError:
        pass
    return f"numerical stack: {', '.join(versions)}; CPU: {cpu}"


def _same_bits(a, b) -> bool:
    """``a`` and ``b`` the same shape and the same bits."""
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


@pytest.fixture
def same_bits():
    """``same_bits(a, b)``: equal bit for bit (two paths of the engine that must give the same numbers)."""
    return _same_bits


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


def _besq_case(p0: float, V: float, p_1: float, alpha: float):
    """``(problem, density, zero_weight)``: ``f = p/p_1``, constant drift ``alpha`` away from the wall, ``alpha p_1 < 1``.

    ``Z = 2 p_1 p`` is the squared Bessel process of dimension ``delta = 2 alpha p_1 < 2``, absorbed at 0 (Feller's
    exit boundary): ``closed_forms.cir_density`` / ``cir_zero_weight`` with ``beta = 0`` (its absorbed transition
    density with ``I_|nu|``, and the non-contact weight ``Q(1 - delta/2, z0/2t)``, ``t = tau = V/2``; A.
    Goeing-Jaeschke and M. Yor, Bernoulli 9, 313 (2003), doi:10.3150/bj/1068128980; tested on its own in
    test_closed_forms).  ``alpha = 0`` is Feller's solution (``Q(1, x) = exp(-x)``)."""
    from diffusion_pr import closed_forms as cf
    from diffusion_pr.models import ProportionalDiffusivity
    from diffusion_pr.problem import FokkerPlanckProblem

    args = (p0, V / 2, 1.0 / p_1, alpha)
    problem = FokkerPlanckProblem(p0, V, ProportionalDiffusivity(p_1), drift=lambda p, tau: np.full_like(p, alpha))
    return problem, (lambda p: cf.cir_density(p, *args)), cf.cir_zero_weight(*args)


@pytest.fixture
def besq_case():
    """``besq_case(p0, V, p_1, alpha)``: the absorbed squared Bessel process as a Fokker-Planck problem with its
    closed-form density and non-contact weight (a constant drift away from an exit wall)."""
    return _besq_case
