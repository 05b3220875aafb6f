"""The compiled staged integration (diffusion_pr.solvers.fv._kernels) against the LAPACK path.

Oracles: LAPACK ``zgtsv`` (scipy) for the pivoted tridiagonal solve, the
LAPACK CRAM of :mod:`diffusion_pr.solvers.fv.cram` for the exponential, and the
numpy stage loop of ``_PythonKernels`` (the engine's loop before the kernels) for the
balance substeps: same algorithm, so they
must agree to round-off (1e-12 relative: a few hundred operations of 1e-16).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import get_lapack_funcs

import diffusion_pr as dp
from diffusion_pr.closures import closure_problem, spectrum_shells
from diffusion_pr.solvers.fv import engine
from diffusion_pr.solvers.fv._kernels import ALPHA, ALPHA0, THETA, cram_apply, gtsv
from diffusion_pr.solvers.fv.cram import expm_tridiagonal


@pytest.mark.parametrize("weak_diagonal", [False, True])
def test_gtsv_matches_lapack(rng, weak_diagonal):
    """Random complex systems; with a weak diagonal every row needs LAPACK's row interchange."""
    n = 57
    dl = rng.normal(size=n - 1) + 1j * rng.normal(size=n - 1)
    du = rng.normal(size=n - 1) + 1j * rng.normal(size=n - 1)
    d = rng.normal(size=n) + 1j * rng.normal(size=n)
    if weak_diagonal:
        d *= 1e-3
    b = rng.normal(size=n) + 1j * rng.normal(size=n)
    ref = get_lapack_funcs("gtsv", dtype=np.complex128)(dl.copy(), d.copy(), du.copy(), b.copy())[3]
    x = b.copy()
    assert gtsv(dl.copy(), d.copy(), du.copy(), x) == 0
    assert np.max(np.abs(x - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_gtsv_reports_singular():
    d = np.array([0.0, 1.0, 1.0], dtype=complex)
    z = np.zeros(2, dtype=complex)
    assert gtsv(z.copy(), d, z.copy(), np.ones(3, dtype=complex)) == 1


def test_cram_apply_matches_lapack_cram(rng):
    n = 300
    lo = rng.uniform(0.1, 2.0, n - 1)
    up = rng.uniform(0.1, 2.0, n - 1)
    diag = -(np.r_[lo, 0.0] + np.r_[0.0, up])  # columns sum to 0: a generator
    y = rng.uniform(size=n)
    ref = expm_tridiagonal(lo, diag, up, 3.7, y)
    out, info = cram_apply(lo, diag, up, 3.7, y, ALPHA, THETA, ALPHA0)
    assert info == 0
    assert np.max(np.abs(out - ref)) <= 1e-13 * np.max(np.abs(ref))


def _matvec(b, y):
    lower, diag, upper = b
    out = diag * y
    out[1:] += lower * y[:-1]
    out[:-1] += upper * y[1:]
    return out


class _PythonKernels:
    """The staged integration written with numpy and LAPACK: the oracle of the compiled kernels.

    ``balanced`` is the algorithm of ``_kernels.balanced_stage`` (midpoint-predicted ``A``, one
    Newton exponential where the mean misses ``p0`` by more than ``mean_tol p0``), as the engine
    ran it before the kernels existed.
    """

    expm = staticmethod(expm_tridiagonal)

    @staticmethod
    def balanced(base, wband, cvec, y, dt, m, p0, mean_tol):
        wl, wd, wu = wband
        n_cram = n_newton = 0
        for _ in range(m):
            l0y, lwy = _matvec(base, y), _matvec(wband, y)
            denom = float(cvec @ lwy)
            A = float(cvec @ l0y) / denom if denom != 0.0 else 0.0
            if denom != 0.0:
                u = y + (0.5 * dt) * (l0y - A * lwy)
                den_u = float(cvec @ _matvec(wband, u))
                if den_u != 0.0:
                    A = float(cvec @ _matvec(base, u)) / den_u
            trial = expm_tridiagonal(base[0] - A * wl, base[1] - A * wd, base[2] - A * wu, dt, y)
            n_cram += 1
            err = float(cvec @ trial) - p0
            if abs(err) > mean_tol * p0 and denom != 0.0:
                A += err / (dt * denom)
                trial = expm_tridiagonal(base[0] - A * wl, base[1] - A * wd, base[2] - A * wu, dt, y)
                n_cram += 1
                n_newton += 1
            y = trial
        return y, n_cram, n_newton


@pytest.mark.parametrize("zeta", [0.01, 1.0])
def test_compiled_staged_path_equals_python_path(monkeypatch, zeta):
    """A balanced closure (96 stages, Newton steps at zeta = 0.01) through both paths, same grid."""
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    prob = closure_problem(spectrum_shells(spec, E_star=8 / 3, n_shells=24), zeta=zeta, E_star=8 / 3,
                           mean_pressure=0.004, closure="local_g1_shell_balanced")
    fast = engine.solve_fv(prob, rtol=1e-4, backend="native", n_cells=40)
    monkeypatch.setattr(engine, "_staged_kernels", lambda: _PythonKernels())  # numpy and LAPACK
    slow = engine.solve_fv(prob, rtol=1e-4, backend="native", n_cells=40)
    assert fast.diagnostics["newton_steps"] == slow.diagnostics["newton_steps"]
    assert np.max(np.abs(fast.density * fast.weights - slow.density * slow.weights)) < 1e-12
    assert abs(fast.zero_weight - slow.zero_weight) < 1e-12


@pytest.mark.parametrize("zeta", [0.25, 4.0])
def test_lamperti_domain_keeps_the_answer(monkeypatch, zeta):
    """The shorter Lamperti domain (fewer cells) gives the answer of the conservative domain within rtol."""
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    prob = closure_problem(spectrum_shells(spec, E_star=8 / 3, n_shells=24), zeta=zeta, E_star=8 / 3,
                           mean_pressure=0.004, closure="local_g1")
    short = engine.solve_fv(prob, rtol=1e-6, backend="native")
    monkeypatch.setattr(engine, "LAMPERTI", False)
    long = engine.solve_fv(prob, rtol=1e-6, backend="native")
    assert short.success and long.success
    assert short.diagnostics["p_max"] < 0.8 * long.diagnostics["p_max"]
    x = np.linspace(0.0, long.diagnostics["p_max"], 4001)
    assert np.max(np.abs(short.cdf(x) - long.cdf(x))) < 2e-6  # both within rtol = 1e-6 of the truth


@pytest.mark.parametrize("zeta", [0.001, 0.01])
def test_balanced_closure_answer_does_not_follow_rtol(zeta):
    """Same question, same answer: a balanced closure at rtol 1e-4 and 1e-5 agrees within 1e-4.

    Its drift cancels the Ito drift of ln p below the floor, so probability
    returns from below and the answer depends on the depth of the domain; the
    depth used to be ln(10/rtol) e-folds and the two answers differed by 7e-4 in
    F(p0/20) at zeta = 0.001 (70x the looser rtol).  Now the depth is fixed
    (engine.BOTTOM_EFOLDS_DRIFT).
    """
    from diffusion_pr.closures import closure_distribution

    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    runs = [closure_distribution(spec, E_star=8 / 3, mean_pressure=0.004, zeta=zeta,
                                 closure="local_g1_shell_balanced", rtol=rtol, n_shells=32) for rtol in (1e-4, 1e-5)]
    assert all(r.success for r in runs)
    assert runs[0].diagnostics["domain_bottom"] == runs[1].diagnostics["domain_bottom"]
    x = np.geomspace(1e-6, 0.05, 400)
    assert abs(runs[0].zero_weight - runs[1].zero_weight) < 1e-4
    assert np.max(np.abs(runs[0].cdf(x) - runs[1].cdf(x))) < 1e-4
