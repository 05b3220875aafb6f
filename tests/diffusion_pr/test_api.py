"""Public API: propagate, pressure_distribution, backend choice, closed-form backend, bad input."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr import closed_forms as cf
from diffusion_pr.fokker_planck.backends import BackendUnavailableError

FIG1 = dict(hurst=0.3, q_min=2 * np.pi / 1024, q_max=2 * np.pi / 32, rms_slope=0.031)


def fig1_spectrum():
    return dp.SelfAffineSpectrum(FIG1["hurst"], FIG1["q_min"], FIG1["q_max"], rms_slope=FIG1["rms_slope"])


def test_import_is_light_and_lazy():
    # a fresh interpreter: importing the package and solving must not load py-pde or FiPy
    code = ("import sys, diffusion_pr as d; r = d.propagate(1.0, 1.0, diffusivity=d.MuserCutoff(0.5), rtol=1e-3); "
            "assert r.success; assert 'pde' not in sys.modules and 'fipy' not in sys.modules, 'heavy import'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    for name in ("SelfAffineSpectrum", "DiscreteSpectrum", "stress_variance", "G1", "propagate",
                 "pressure_distribution", "PressureDistribution", "FokkerPlanckProblem",
                 "mirror_gaussian_density", "feller_density", "MuserCutoff", "PressureFactor"):
        assert name in dir(dp) and getattr(dp, name) is not None


def test_spectrum_and_closure_solve_import_no_scipy_integrate_or_special():
    """A fresh interpreter: building a spectrum and solving a shell closure imports neither ``scipy.integrate``
    (0.43 s here; the spectrum needs it only for ``integrate(method="quad")``) nor ``scipy.special`` (0.21 s; only
    the closed forms evaluate it, not the backend's ``exact_kind`` that every ``"auto"`` solve asks). Oracle:
    ``sys.modules``; then the closed form itself does import ``scipy.special``."""
    code = ("import sys, numpy as np, diffusion_pr as d\n"
            "S = d.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)\n"
            "r = d.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, closure='local_g1', "
            "rtol=1e-4)\n"
            "assert r.success\n"
            "heavy = sorted(m for m in ('scipy.integrate', 'scipy.special') if m in sys.modules)\n"
            "assert not heavy, heavy\n"
            "assert d.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004).backend == 'closed_form'\n"
            "assert 'scipy.special' in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)


def test_propagate_default_is_the_exact_mirror_gaussian():
    r = dp.propagate(1.0, 1.0)
    assert r.backend == "closed_form" and r.success
    # Gauss-Legendre panels integrate the closed form to round-off (independent: erfc, moments formula)
    assert r.zero_weight == pytest.approx(cf.persson_zero_weight(1.0, 1.0), rel=1e-15)
    assert abs(r.mass - 1.0) < 1e-13
    assert abs(r.mean - 1.0) < 1e-13
    m = cf.mirror_gaussian_moments(1.0, 1.0)
    assert r.moment(2, central=True) == pytest.approx(m.variance, rel=1e-12)


@pytest.mark.parametrize("p0, p1", [(1.0, 1.0), (0.01, 1.0), (3.0, 0.1), (1e-3, 1e3)])
def test_closed_form_feller_moments(p0, p1):
    r = dp.propagate(p0, 1.0, diffusivity=dp.ProportionalDiffusivity(p1))
    m = cf.feller_moments(p0, 0.5, 1.0 / p1)
    assert r.backend == "closed_form"
    assert abs(r.mass - 1.0) < 1e-12  # quadrature of the exact density
    assert r.mean == pytest.approx(p0, rel=1e-11)
    assert r.moment(2, central=True) == pytest.approx(m.variance, rel=1e-10)  # 2 a p0 tau
    assert r.zero_weight == pytest.approx(m.zero_weight, rel=1e-14)


@pytest.mark.parametrize(
    "kwargs, expected",
    [
        ({}, "closed_form"),
        ({"diffusivity": dp.SharpCutoff()}, "closed_form"),
        ({"diffusivity": dp.PressureFactor(dp.SharpCutoff(), dp.GaussianTail())}, "closed_form"),
        ({"diffusivity": lambda p: 2.0 * np.ones_like(p)}, "closed_form"),  # constant: probed
        ({"diffusivity": lambda p: 3.0 * p}, "closed_form"),  # proportional: probed
        ({"diffusivity": dp.ProportionalDiffusivity(2.0)}, "closed_form"),
        ({"diffusivity": dp.MuserCutoff(0.3)}, "native"),
        ({"diffusivity": dp.PressureFactor(dp.SmoothstepCutoff(0.3), dp.GaussianTail())}, "native"),
        ({"diffusivity": dp.PressureFactor(dp.SharpCutoff(), dp.LinearTail(1.0))}, "native"),
        ({"drift": lambda p, t: 0.1 * np.ones_like(p)}, "native"),
    ],
)
def test_auto_backend_choice(kwargs, expected):
    r = dp.propagate(1.0, 1.0, rtol=1e-3, **kwargs)
    assert r.backend == expected
    assert r.diagnostics["backend_requested"] == "auto"


def test_constant_diffusivity_closed_form_scales_the_variance():
    # f = 2 is the mirror Gaussian of variance 2 V
    r = dp.propagate(1.0, 1.0, diffusivity=lambda p: 2.0 * np.ones_like(p))
    assert r.zero_weight == pytest.approx(cf.persson_zero_weight(1.0, 2.0), rel=1e-14)


def test_native_and_closed_form_agree_through_the_api():
    exact = dp.propagate(0.7, 1.0)
    num = dp.propagate(0.7, 1.0, backend="native", rtol=1e-6)
    q = np.linspace(0.0, 4.0, 41)
    # CDFs differ by at most the L1 error (<= rtol) plus the interpolation of the FV CDF inside cells
    assert np.max(np.abs(exact.cdf(q) - num.cdf(q))) < 2e-6
    assert num.zero_weight == pytest.approx(exact.zero_weight, abs=1e-6)


def test_fig1_persson_numbers():
    # SPEC section 3: sqrt(V0) = 0.041333 and Persson a_r = 0.07709 for the Fig. 1 continuum spectrum
    r = dp.pressure_distribution(fig1_spectrum(), E_star=8 / 3, mean_pressure=0.004, closure="second_order")
    assert r.backend == "closed_form"
    assert np.sqrt(r.diagnostics["stress_variance"]) == pytest.approx(0.041333, rel=2e-5)
    assert r.contact_fraction == pytest.approx(0.07709, abs=1e-5)


def test_zeta_uses_G1_variance():
    s = fig1_spectrum()
    r = dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, closure="second_order")
    V = dp.stress_variance(s, E_star=8 / 3, mean_pressure=0.004, zeta=0.25)
    V0 = dp.stress_variance(s, E_star=8 / 3, mean_pressure=0.004)
    assert r.diagnostics["stress_variance"] == V and V < V0
    assert r.zero_weight == pytest.approx(cf.persson_zero_weight(0.004, V), rel=1e-13)


def test_seed_cutoff_scene_converges():
    r = dp.pressure_distribution(fig1_spectrum(), E_star=8 / 3, mean_pressure=0.004, zeta=0.0,
                                 cutoff="muser", p_c=0.0068, rtol=1e-5)
    assert r.backend == "native" and r.success and r.error_estimate <= 1e-5
    assert abs(r.mass - 1.0) < 1e-11 + r.error_estimate and abs(r.mean - 0.004) < 1e-5 * 0.004
    assert np.all(r.density >= 0.0)


def test_zero_drift_in_magnification_equals_no_drift():
    # the eta -> tau mapping with A = 0 must reproduce the autonomous solve
    s = fig1_spectrum()
    kw = dict(E_star=8 / 3, mean_pressure=0.004, cutoff="raised_cosine", p_c=0.003, rtol=1e-5)
    a = dp.pressure_distribution(s, **kw)
    b = dp.pressure_distribution(s, drift=lambda p, eta: np.zeros_like(p), **kw)
    q = np.linspace(0.0, 0.2, 81)
    assert np.max(np.abs(a.cdf(q) - b.cdf(q))) < 2e-5  # both within rtol of the truth


def test_drift_proportional_to_D_shifts_the_mean():
    # A(p, eta) = c D(eta) maps to a constant a = c in tau: far from the wall the mean moves by c V/2
    s = fig1_spectrum()
    c, p0 = 0.5, 0.5  # p0 = 12 sqrt(V0): the wall is irrelevant

    def drift(p, eta):
        return c * dp.diffusivity_vs_magnification(s, eta, E_star=8 / 3, mean_pressure=p0) * np.ones_like(p)

    r = dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=p0, drift=drift, rtol=1e-5)
    V = r.diagnostics["stress_variance"]
    assert r.backend == "native" and r.success
    # the drift is divided by the exact D(eta): a = c. The shift c V/2 is 4e-4 p0 here, so the mean (measured
    # 5e-9 relative, L1 error 1e-5 times a spread 1e-3 of p0) checks the drift's size, not the map's fine
    # structure (test_the_magnification_map_is_exact does); tolerance 1e-7 relative
    assert r.mean == pytest.approx(p0 + c * V / 2, rel=1e-7)
    # a uniform drift leaves the Gaussian's variance V: measured 1e-6 relative (the cells' second moment), 1e-5
    assert r.moment(2, central=True) == pytest.approx(V, rel=1e-5)


def test_the_magnification_map_is_exact():
    # A(p, eta) = -c D(eta) (p - p0) (V(eta) - V(1)) / V^(3/2) maps to a(p, tau) = -c (p - p0) 2 tau / V^(3/2)
    # exactly when eta(tau) solves (V(eta) - V(1))/2 = tau; propagate with that tau drift written by hand is the
    # oracle. Both runs integrate the same segments on the same grids, so they agree to the map's round-off:
    # tolerance 1e-9 (measured 1e-12). The linear 513-node map they replaced misses by 1.1e-7 here.
    s = fig1_spectrum()
    p0, c = 0.004, 1.0
    kw = dict(E_star=8 / 3, mean_pressure=p0)
    V, V1 = float(dp.stress_variance(s, **kw)), float(dp.variance_vs_magnification(s, 1.0, **kw))
    scale = V ** 1.5

    def drift(p, eta):
        D = dp.diffusivity_vs_magnification(s, eta, **kw)
        return -c * D * (p - p0) * (dp.variance_vs_magnification(s, eta, **kw) - V1) / scale

    p_c = 0.3 * np.sqrt(V)
    a = dp.pressure_distribution(s, cutoff="muser", p_c=p_c, drift=drift, rtol=1e-6, **kw)
    b = dp.propagate(p0, V - V1, diffusivity=dp.PressureFactor(dp.MuserCutoff(p_c)), rtol=1e-6,
                     drift=lambda p, tau: -c * (p - p0) * 2.0 * tau / scale)
    assert a.success and b.success and a.diagnostics["levels"] == b.diagnostics["levels"]
    q = np.linspace(0.0, 6.0 * np.sqrt(V), 2001)
    assert abs(a.zero_weight - b.zero_weight) < 1e-9
    assert np.max(np.abs(a.cdf(q) - b.cdf(q))) < 1e-9


def test_the_magnification_map_inverts_the_variance():
    # the map itself against its definition (V(eta) - V(1))/2 = tau, to round-off, at the table's nodes, between
    # them and at both ends; and D(eta) returned with it is the exact diffusivity there
    s = dp.SelfAffineSpectrum(0.7, 1.0, 1e4, rms_slope=0.1)  # 4 decades: the table's intervals are 2% wide
    kw = dict(E_star=1.0, mean_pressure=0.02, zeta=0.01)
    eta = np.geomspace(1.0, 1e4, 513)
    v = dp.variance_vs_magnification(s, eta, **kw)
    seen = []

    def drift_of_eta(p, e):  # A = D(eta): the drift in tau is A / D = 1 where the map divides by the exact D
        seen.append(e)
        return dp.diffusivity_vs_magnification(s, e, **kw) * np.ones_like(p)

    prob = dp.FokkerPlanckProblem.from_magnification(
        mean_pressure=0.02, eta=eta, variance_of_eta=v, pressure_factor=dp.PressureFactor(dp.SharpCutoff()),
        drift_of_eta=drift_of_eta,
        variance_function=lambda e: dp.variance_vs_magnification(s, e, **kw),
        diffusivity_function=lambda e: dp.diffusivity_vs_magnification(s, e, **kw))
    taus = np.r_[0.0, np.linspace(0.0, prob.tau_end, 37)[1:-1], 0.5 * (v[100:103] - v[0]), prob.tau_end]
    a = np.array([prob.drift(np.array([0.02]), float(t))[0] for t in taus])
    e = np.array(seen)
    np.testing.assert_allclose(a, 1.0, rtol=0.0, atol=1e-14)
    assert np.allclose(0.5 * (dp.variance_vs_magnification(s, e, **kw) - v[0]), taus,
                       rtol=0.0, atol=16 * np.finfo(float).eps * prob.tau_end)
    assert e[0] == pytest.approx(1.0, rel=1e-12) and e[-1] == pytest.approx(1e4, rel=1e-12)
    with pytest.raises(ValueError, match="go together"):
        dp.FokkerPlanckProblem.from_magnification(
            mean_pressure=0.02, eta=eta, variance_of_eta=v, pressure_factor=dp.PressureFactor(dp.SharpCutoff()),
            drift_of_eta=lambda p, e: 0 * p, variance_function=lambda e: e)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: dp.propagate(1.0, -1.0), "variance"),
        (lambda: dp.propagate(1.0, np.nan), "variance"),
        (lambda: dp.propagate(0.0, 1.0), "mean_pressure"),
        (lambda: dp.propagate(1.0, 1.0, diffusivity=3.0), "diffusivity"),
        (lambda: dp.propagate(1.0, 1.0, drift="up"), "drift"),
        (lambda: dp.propagate(1.0, 1.0, backend="bogus"), "backend"),
        (lambda: dp.propagate(1.0, 1.0, rtol=0.0), "rtol"),
        (lambda: dp.pressure_distribution(fig1_spectrum(), E_star=1.0, mean_pressure=0.01,
                                          cutoff="muser", p_c=0.0), "p_c"),
        (lambda: dp.pressure_distribution(fig1_spectrum(), E_star=1.0, mean_pressure=0.01,
                                          cutoff="muser", p_c=-1.0), "p_c"),
        (lambda: dp.pressure_distribution(fig1_spectrum(), E_star=1.0, mean_pressure=0.01, zeta=-1.0), "zeta"),
        (lambda: dp.pressure_distribution(fig1_spectrum(), E_star=np.nan, mean_pressure=0.01), "E_star"),
        (lambda: dp.pressure_distribution(fig1_spectrum(), E_star=1.0, mean_pressure=0.01, cutoff="nope"), "cutoff"),
        (lambda: dp.SelfAffineSpectrum(0.3, 0.1, 1.0, rms_slope=np.nan), "rms_slope"),
        (lambda: dp.propagate(1.0, 1.0, diffusivity=dp.MuserCutoff(0.5), backend="closed_form"), "closed_form"),
    ],
)
def test_bad_input_gives_clear_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_nan_spectrum_is_rejected():
    class NaNSpectrum(dp.Spectrum):
        q_min, q_max = 1.0, 10.0

        def quadrature(self):
            return np.array([1.0, 2.0]), np.array([np.nan, 1.0])

        def cumulative(self, weight, q):
            return np.full(np.shape(q), np.nan)

    with pytest.raises(ValueError, match="variance"):
        dp.pressure_distribution(NaNSpectrum(), E_star=1.0, mean_pressure=0.01)


@pytest.mark.parametrize("name, module, extra", [("pypde", "pde", "pypde"), ("fipy", "fipy", "fipy")])
def test_missing_optional_backend_names_the_extra(monkeypatch, name, module, extra):
    monkeypatch.setitem(sys.modules, module, None)  # makes `import module` raise ImportError
    with pytest.raises(BackendUnavailableError, match=rf"pip install 'diffusion-pr\[{extra}\]'"):
        dp.propagate(1.0, 1.0, backend=name)
    assert not dp.is_available(name)


def test_plot_returns_axes():
    import matplotlib

    matplotlib.use("Agg")
    ax = dp.propagate(1.0, 1.0).plot()
    assert ax is not None


# ---------------------------------------------------------------- StagedProblem contract (CONTRACT.md)
def test_staged_problem_validation_and_auto_backend():
    one = lambda p: np.ones_like(p)  # noqa: E731
    with pytest.raises(ValueError, match="duration"):
        dp.Stage(-1.0, one)
    with pytest.raises(ValueError, match="diffusivity"):
        dp.Stage(1.0, 3.0)
    with pytest.raises(ValueError, match="stages"):
        dp.StagedProblem(1.0, ())
    with pytest.raises(ValueError, match="mean_pressure"):
        dp.StagedProblem(-1.0, (dp.Stage(1.0, one),))
    # two stages of f = 1 are one stage of the summed duration: the mirror Gaussian (oracle: closed form)
    staged = dp.StagedProblem(1.0, (dp.Stage(0.2, one), dp.Stage(0.3, one)))
    assert staged.variance == pytest.approx(1.0)
    r = dp.solve_problem(staged, rtol=1e-6)
    assert r.backend == "native" and r.success
    assert r.zero_weight == pytest.approx(dp.persson_zero_weight(1.0, 1.0), abs=1e-6)


def test_zeta_sweep_equals_single_calls():
    """pressure_distributions solves each wall on its own: the same cells and masses, bit for bit, as single calls
    (second order and a balanced closure), in the order given."""
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    zetas = [1.0, 0.01, 0.25]
    for kw in (dict(cutoff="muser", p_c=0.0027), dict(closure="local_g1_balanced")):
        kw.update(E_star=8 / 3, mean_pressure=0.004, rtol=1e-5)
        sweep = dp.pressure_distributions(spec, zetas=zetas, **kw)
        for z, a in zip(zetas, sweep):
            b = dp.pressure_distribution(spec, zeta=z, **kw)
            assert a.success and np.array_equal(a.edges, b.edges) and np.array_equal(a.density, b.density)
            assert a.zero_weight == b.zero_weight


@pytest.mark.parametrize("bad, match", [
    (dict(zetas=[]), "non-empty one-dimensional"),
    (dict(zetas=[[0.1, 0.2]]), "non-empty one-dimensional"),
    (dict(zetas=[0.1], zeta=0.1), "zeta is set by the sweep"),
    (dict(zetas=[0.1], n_start=64), "unknown option"),
])
def test_zeta_sweep_rejects_bad_input(bad, match):
    spec = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    with pytest.raises(ValueError, match=match):
        dp.pressure_distributions(spec, E_star=8 / 3, mean_pressure=0.004, **bad)


def test_warm_up_compiles_the_engine_and_closure_kernels_and_checks_its_backend():
    """In a fresh interpreter ``warm_up()`` leaves the closures' row kernel and the staged kernels compiled
    (loaded), and an unknown backend is an error naming the parameter."""
    code = ("import diffusion_pr as dp; from diffusion_pr.closures._kernels import model_rows; "
            "from diffusion_pr.fokker_planck import _kernels; assert dp.warm_up() >= 0.0; "
            "assert model_rows.signatures and _kernels.staged_run_rows.signatures")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=600)
    with pytest.raises(ValueError, match="backend"):
        dp.warm_up("nope")


def test_default_closure_follows_the_scene():
    """closure=None: the held-out choices (local_g1_shell_balanced on exponential walls, sum_rule at the hard
    wall, a closed form); the paper's second order where one of its own options is given."""
    s = fig1_spectrum()
    kw = dict(E_star=8 / 3, mean_pressure=0.004)
    soft = dp.pressure_distribution(s, zeta=0.25, **kw, rtol=1e-4)
    assert soft.diagnostics["closure"] == dp.DEFAULT_CLOSURE == "local_g1_shell_balanced"
    paper = dp.pressure_distribution(s, zeta=0.25, cutoff="muser", p_c=0.0027, **kw)
    assert paper.diagnostics["closure"] == "second_order"
    hard = dp.pressure_distribution(s, **kw)
    assert hard.diagnostics["closure"] == dp.HARD_WALL_DEFAULT == "sum_rule" and hard.backend == "closed_form"
    persson = dp.pressure_distribution(s, closure="second_order", **kw)
    assert persson.contact_area() < 0.8 * hard.contact_area()
