"""No silent failure: a bad input is a named error in under a second, a failed solve warns.

Every error names the parameter and its value; each case below was a wrong answer, a
traceback or a silent success before it was caught at the boundary.
"""
from __future__ import annotations

import time
import warnings

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr.cli import main

S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
SCENE = dict(E_star=8 / 3, mean_pressure=0.004)


def _fast_error(call, *words, error=ValueError):
    """``call()`` raises ``error`` within a second, its message holding every one of ``words``."""
    t0 = time.perf_counter()
    with pytest.raises(error) as exc:
        call()
    assert time.perf_counter() - t0 < 1.0
    for word in words:
        assert word in str(exc.value), (word, str(exc.value))
    return exc.value


# ----------------------------------------------------------------------------- failed results warn
def test_a_failed_solve_warns_at_every_public_entry_point():
    """max_cells=200 cannot reach rtol 1e-12 (the mirror Gaussian needs ~3e4 cells): success False, and a warning."""
    assert issubclass(dp.ConvergenceWarning, UserWarning)
    calls = [
        lambda: dp.propagate(1.0, 1.0, backend="native", rtol=1e-12, max_cells=200),
        lambda: dp.solve_problem(dp.FokkerPlanckProblem(1.0, 1.0), backend="native", rtol=1e-12, max_cells=200),
        lambda: dp.pressure_distribution(S, **SCENE, zeta=0.25, backend="native", rtol=1e-12, max_cells=200),
        lambda: dp.pressure_distributions(S, **SCENE, zetas=[0.25], backend="native", rtol=1e-12, max_cells=200)[0],
    ]
    for call in calls:
        with pytest.warns(dp.ConvergenceWarning, match="misses rtol") as record:
            r = call()
        assert not r.success and r.message in str(record[0].message)
    with warnings.catch_warnings():  # a user can silence them by class
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", dp.ConvergenceWarning)
        assert not dp.propagate(1.0, 1.0, backend="native", rtol=1e-12, max_cells=200).success
        assert dp.propagate(1.0, 1.0, backend="native", rtol=1e-4).success  # a success does not warn


def test_the_reported_pypde_failure_warns():
    """The reported case: py-pde returned success=False without a word (2 s here)."""
    pytest.importorskip("pde")
    with pytest.warns(dp.ConvergenceWarning, match="backend 'pypde'"):
        assert not dp.propagate(1.0, 1.0, backend="pypde", rtol=1e-12, max_cells=200).success


# ----------------------------------------------------------------------------- options a solve would ignore
def test_closed_form_backend_for_a_closure_is_a_clear_error():
    for closure in ("local_g1", "local_g1_balanced", "local_g1_shell_balanced"):
        _fast_error(lambda: dp.pressure_distribution(S, **SCENE, zeta=0.25, closure=closure,
                                                     backend="closed_form"), "closed_form")


def test_lognormal_gap_refuses_the_backends_and_options_it_ignores():
    for backend in ("native", "pypde", "fipy"):
        _fast_error(lambda: dp.pressure_distribution(S, **SCENE, zeta=0.25, closure="lognormal_gap",
                                                     backend=backend), "backend", repr(backend), "closed form")
    _fast_error(lambda: dp.pressure_distribution(S, **SCENE, zeta=0.25, closure="lognormal_gap", max_cells=100),
                "max_cells")
    r = dp.pressure_distribution(S, **SCENE, zeta=0.25, closure="lognormal_gap", backend="closed_form")
    assert r.success and r.mean == pytest.approx(0.004, rel=1e-12)


def test_sharp_cutoff_refuses_a_cutoff_pressure():
    _fast_error(lambda: dp.pressure_distribution(S, **SCENE, zeta=0.25, cutoff="sharp", p_c=0.002),
                "p_c", "0.002", "sharp")
    _fast_error(lambda: dp.make_cutoff("sharp", 0.002), "p_c")


def test_p_floor_where_the_wall_is_reached_is_refused():
    """f(0+) > 0 (sharp cutoff, f = 1): p = 0 absorbs, there is no floor to set."""
    _fast_error(lambda: dp.propagate(1.0, 1.0, backend="native", p_floor=1e-3), "p_floor", "0.001")
    f = dp.PressureFactor(dp.SmoothstepCutoff(0.5))  # f ~ p^3: the floor is honoured
    r = dp.propagate(1.0, 1.0, diffusivity=f, backend="native", p_floor=1e-3, rtol=1e-4)
    assert r.success and r.diagnostics["p_floor"] == 1e-3


# ----------------------------------------------------------------------------- numbers out of range
@pytest.mark.parametrize("call, name", [
    (lambda: dp.propagate(np.complex128(1 + 1j), 1.0), "mean_pressure"),
    (lambda: dp.propagate(1.0, np.array(1 + 0.5j)), "variance"),
    (lambda: dp.pressure_distribution(S, E_star=np.complex128(8 / 3 + 1j), mean_pressure=0.004), "E_star"),
    (lambda: dp.pressure_distributions(S, **SCENE, zetas=np.array([0.25 + 1j])), "zetas"),
    (lambda: dp.stress_variance(S, E_star=8 / 3, mean_pressure=0.004, zeta=np.array([0.1 + 0.1j])), "zeta"),
    (lambda: dp.DiscreteSpectrum.from_heights(np.ones((64, 64)) * (1 + 1j), 1.0), "heights"),
])
def test_complex_inputs_are_refused(call, name):
    err = _fast_error(call, name, "real", error=dp.InputTypeError)
    assert isinstance(err, TypeError) and isinstance(err, ValueError)


def test_negative_diffusivity_names_the_diffusivity():
    _fast_error(lambda: dp.propagate(1.0, 1.0, diffusivity=lambda p: -np.ones_like(p)), "diffusivity", ">= 0",
                "-1.0")


def test_too_many_cells_is_a_limit_error_not_a_memory_error():
    _fast_error(lambda: dp.propagate(1.0, 1.0, backend="native", n_cells=10**9), "n_cells", "1000000000",
                "max_cells")
    _fast_error(lambda: dp.propagate(1.0, 1.0, backend="native", max_cells=10**12), "max_cells")


def test_an_overflowing_modulus_names_e_star():
    _fast_error(lambda: dp.pressure_distribution(S, E_star=1e300, mean_pressure=0.004), "E_star", "1e+300")
    _fast_error(lambda: dp.stress_variance(S, E_star=1e300, mean_pressure=0.004), "E_star")


# ----------------------------------------------------------------------------- command line
def _cli_error(argv, *words, capsys):
    t0 = time.perf_counter()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: usage error
        code = exc.code
    assert time.perf_counter() - t0 < 1.0
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)


def test_cli_bad_inputs_fail_fast_naming_the_option(tmp_path, capsys, monkeypatch):
    import gfmd_ref

    monkeypatch.setattr(gfmd_ref, "solve_contact", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    out = ["--out", str(tmp_path / "o")]
    _cli_error(["theory", "--out", "/proc/x.csv"], "--out", "/proc/x.csv", capsys=capsys)
    _cli_error(["fig1", "--backend", "closed_form"] + out, "--backend", "closed_form", capsys=capsys)
    _cli_error(["fig1", "--tol", "10"] + out, "tol", capsys=capsys)
    _cli_error(["fig1", "--n", "3"] + out, "--n", "64", capsys=capsys)
    _cli_error(["make-reference", "--n", "10"] + out, "--n", "64", capsys=capsys)
    _cli_error(["make-reference", "--zetas", ",,,"] + out, "--zetas", capsys=capsys)
    _cli_error(["fig1", "--zetas", ","] + out, "--zetas", capsys=capsys)
    _cli_error(["make-reference", "--seeds"] + out, "--seeds", capsys=capsys)


def test_generate_reference_refuses_empty_or_undersampled_work(tmp_path):
    from diffusion_pr.jobs.reference_data import generate_reference

    _fast_error(lambda: generate_reference(zetas=(), out_dir=tmp_path), "zetas")
    _fast_error(lambda: generate_reference(zetas=(None,), seeds=(), out_dir=tmp_path), "seeds")
    _fast_error(lambda: generate_reference(zetas=(None,), n=32, out_dir=tmp_path), "n", "64")


def test_run_fig1_refuses_a_gfmd_tolerance_before_any_work():
    """tol=10 would let GFMD stop after 0 iterations; refused before the theory curves (well under a second)."""
    from diffusion_pr.jobs.fig1 import run_fig1

    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"tol must lie in \(0.0, 0.1\]"):
        run_fig1(n=64, tol=10, out_dir=None)
    assert time.perf_counter() - t0 < 1.0
