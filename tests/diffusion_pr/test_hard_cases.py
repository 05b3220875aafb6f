"""Hard cases: stable, conservative, non-negative over wide ranges of p0/sqrt(V) (1e-3 ... 10), p_c (1e-4 ... 1),
magnification (1e4), zeta (1e-4 ... 10) and Hurst exponent (0.1 ... 0.9).

Every case asserts: success with the estimate below rtol, total probability
(continuous part + zero weight) 1 to within the error estimate (the outflow at
the wall is booked exactly; extrapolation may move tail mass), mean pressure p0 to rtol when there is no drift (force
balance), no negative density.  Where a closed form exists (sharp cutoff) the
zero weight is also compared with it.  rtol = 1e-4 keeps the file fast.
"""
from __future__ import annotations

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr import closed_forms as cf

RTOL = 1e-4


def check_sound(r, p0: float, *, drift: bool = False) -> None:
    assert r.success, r.message
    assert r.error_estimate <= RTOL
    # the exponential conserves mass to round-off; the Richardson step may move the tails' mass by
    # at most what it adds to the estimate
    assert abs(r.mass - 1.0) < 1e-10 + r.error_estimate
    assert np.all(r.density >= 0.0) and np.all(np.isfinite(r.density))
    assert 0.0 <= r.zero_weight <= 1.0
    if not drift:
        assert abs(r.mean - p0) <= RTOL * p0


@pytest.mark.parametrize("ratio", [1e-3, 1e-2, 0.1, 1.0, 10.0])
def test_p0_over_sqrtV_sharp_native(ratio):
    # native on the mirror-Gaussian problem, from nearly-all-absorbed to no absorption
    r = dp.propagate(ratio, 1.0, backend="native", rtol=RTOL)
    check_sound(r, ratio)
    assert abs(r.zero_weight - cf.persson_zero_weight(ratio, 1.0)) <= RTOL


@pytest.mark.parametrize("ratio", [1e-3, 1e-2, 0.1, 1.0, 10.0])
@pytest.mark.parametrize("cutoff", ["muser", "smoothstep"])
def test_p0_over_sqrtV_smooth_cutoffs(ratio, cutoff):
    f = dp.PressureFactor(dp.make_cutoff(cutoff, 0.5), dp.GaussianTail())
    check_sound(dp.propagate(ratio, 1.0, diffusivity=f, rtol=RTOL), ratio)


@pytest.mark.parametrize("p_c", [1e-4, 1e-2, 1.0])
@pytest.mark.parametrize("cutoff", ["muser", "raised_cosine", "smoothstep"])
def test_cutoff_pressure_range(p_c, cutoff):
    f = dp.PressureFactor(dp.make_cutoff(cutoff, p_c), dp.GaussianTail())
    r = dp.propagate(1.0, 1.0, diffusivity=f, rtol=RTOL)
    check_sound(r, 1.0)
    if cutoff != "smoothstep" and p_c <= 1e-2:
        # f ~ p^2 near 0: the creeping peak falls below the wall floor, so a tiny p_c
        # reproduces Persson's non-contact weight (the sharp-cutoff limit)
        assert r.zero_weight == pytest.approx(cf.persson_zero_weight(1.0, 1.0), abs=5e-3)


@pytest.mark.parametrize("tail", [("linear", 0.5), ("max_linear", 2.0)])
def test_exponential_tails(tail):
    f = dp.PressureFactor(dp.SharpCutoff(), dp.make_tail(*tail))
    check_sound(dp.propagate(1.0, 1.0, diffusivity=f, rtol=RTOL), 1.0)


@pytest.mark.parametrize("hurst", [0.1, 0.9])
@pytest.mark.parametrize("zeta", [1e-4, 10.0])
def test_wide_magnification_range_with_drift(hurst, zeta):
    # q_max/q_min = 1e4 and a restoring drift A = -D(eta) (p - p0)/(2 sqrt(V)): exercises the eta path
    s = dp.SelfAffineSpectrum(hurst, 1.0, 1e4, rms_slope=0.1)
    p0 = 0.02
    V = dp.stress_variance(s, E_star=1.0, mean_pressure=p0, zeta=zeta)

    def drift(p, eta):
        D = dp.diffusivity_vs_magnification(s, eta, E_star=1.0, mean_pressure=p0, zeta=zeta)
        return -0.5 * D * (p - p0) / np.sqrt(V)

    r = dp.pressure_distribution(s, E_star=1.0, mean_pressure=p0, zeta=zeta, cutoff="smoothstep",
                                 p_c=0.3 * np.sqrt(V), drift=drift, rtol=RTOL)
    check_sound(r, p0, drift=True)
    # a drift towards p0 cannot move the mean away from it by more than the error
    assert abs(r.mean - p0) <= RTOL * p0 + 1e-3 * np.sqrt(V)


@pytest.mark.parametrize("zeta", [1e-4, 1e-2, 1.0, 10.0])
@pytest.mark.parametrize("hurst", [0.1, 0.5, 0.9])
def test_zeta_and_hurst_ranges(zeta, hurst):
    s = dp.SelfAffineSpectrum(hurst, 1.0, 1e4, rms_slope=0.1)
    p0 = 0.02
    V = dp.stress_variance(s, E_star=1.0, mean_pressure=p0, zeta=zeta)
    r = dp.pressure_distribution(s, E_star=1.0, mean_pressure=p0, zeta=zeta, cutoff="muser",
                                 p_c=0.5 * np.sqrt(V), rtol=RTOL)
    assert r.backend == "native"
    check_sound(r, p0)
    assert r.diagnostics["stress_variance"] == V


def test_seed_figure1_cutoffs_all_converge():
    # the paper's fitted p_c values for the Fig. 1 surface (SPEC section 6)
    s = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    for zeta, p_c in ((0.001, 0.0068), (0.01, 0.0082), (0.25, 0.0027), (4.0, 0.0027)):
        r = dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, cutoff="muser",
                                     p_c=p_c, rtol=RTOL)
        check_sound(r, 0.004)


# ------------------------------------------------------------------ user cutoffs, clear errors, extreme inputs
P_C = 0.0027


@pytest.mark.parametrize("form", ["1-cos", "2sin2"])
def test_literal_cutoff_as_user_callable_equals_builtin(form):
    """The user's literal cutoff (1 - cos underflows to 0 near p = 0) gives the built-in answer: the probe
    finds k = 2 and the jump at p_c, so the grid is the same (oracle: the built-in MuserCutoff)."""
    if form == "1-cos":
        lit = lambda p: np.where(p < P_C, 1 - np.cos(np.pi * p / P_C), 1.0)  # noqa: E731
    else:
        lit = lambda p: np.where(p < P_C, 2 * np.sin(0.5 * np.pi * p / P_C) ** 2, 1.0)  # noqa: E731
    a = dp.propagate(0.004, 0.03**2, diffusivity=lit, backend="native", rtol=1e-6)
    b = dp.propagate(0.004, 0.03**2, diffusivity=dp.PressureFactor(dp.MuserCutoff(P_C), dp.GaussianTail()),
                     backend="native", rtol=1e-6)
    assert a.success and b.success
    assert np.min(np.abs(a.edges - P_C)) < 1e-12 * P_C and a.p.size == b.p.size  # the jump located by bisection
    # 2 sin^2 is the built-in's formula: agreement to round-off.  1 - cos is a different function in floating
    # point: it is exactly 0 below p = 1.3e-11 and a staircase up to about 1e-9 (far below the floor 4e-9),
    # which moves 2-4e-6 of probability (measured); the solver's own error is 2e-7 here
    tol = 1e-9 if form == "2sin2" else 1e-5
    assert abs(a.zero_weight - b.zero_weight) < tol
    assert np.sum(np.abs(a.density - b.density) * a.weights) < tol


@pytest.mark.parametrize("call, match", [
    (lambda: dp.propagate(1.0, 1.0, diffusivity=lambda p: 0 * p), "diffusivity is 0"),
    (lambda: dp.propagate(1.0, 1.0, diffusivity=lambda p: np.ones(3)), "vectorized"),
    (lambda: dp.propagate(1e-300, 1.0, backend="native"), "mean_pressure/spread"),
    (lambda: dp.propagate(1e200, 1e300), "mean_pressure/sqrt"),
    (lambda: dp.propagate(1e150, 1e-300, backend="native"), "mean_pressure/spread"),
    (lambda: dp.propagate(1.0, 1.0, backend="native", n_cells=0), "n_cells"),
    (lambda: dp.propagate(10.0, 1.0, drift=lambda p, t: 100 + 0 * p, backend="native"), "Peclet"),
    (lambda: dp.propagate(1.0, 1.0, closure="local_g1"), "unknown option"),
    (lambda: dp.SelfAffineSpectrum(0.3, 1.0, 1e300, rms_slope=0.1), "overflow"),
])
def test_clear_errors_fast(call, match):
    import time

    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=match):
        call()
    assert time.perf_counter() - t0 < 5.0  # generous on a loaded CI machine; measured < 0.1 s


def test_extreme_but_valid_inputs_give_correct_results():
    r = dp.propagate(1e-8, 1.0, backend="native", rtol=1e-6)  # nearly all absorbed at once
    assert r.success and r.zero_weight == pytest.approx(cf.persson_zero_weight(1e-8, 1.0), abs=1e-6)
    r = dp.propagate(1e6, 1.0)  # the closed form far from the wall: cost independent of p0/sqrt(V)
    assert r.success and r.zero_weight == 0.0 and r.p.size < 2000
    with pytest.warns(dp.ConvergenceWarning, match="misses rtol"):  # unreachable: a clear failure, not a hang
        r = dp.propagate(1.0, 1.0, backend="native", rtol=1e-14)
    assert not r.success and "misses rtol" in r.message


def test_stress_variance_vectorized_over_mean_pressure():
    s = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    v = dp.stress_variance(s, E_star=8 / 3, mean_pressure=[0.004, 0.008], zeta=0.25)
    assert v.shape == (2,)
    assert v[1] == pytest.approx(dp.stress_variance(s, E_star=8 / 3, mean_pressure=0.008, zeta=0.25), rel=1e-14)
    assert v[0] == pytest.approx(dp.stress_variance(s, E_star=8 / 3, mean_pressure=0.004, zeta=0.25), rel=1e-14)


def test_results_are_not_mutated_by_the_api():
    r1 = dp.pressure_distribution(dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031),
                                  E_star=8 / 3, mean_pressure=0.004, zeta=1.0, cutoff="smoothstep", p_c=0.0027,
                                  rtol=1e-4)
    assert "stress_variance" in r1.diagnostics and r1.diagnostics["backend_requested"] == "auto"


def test_a_grid_floor_above_p0_is_not_a_silent_success():
    """With the grid floor placed above p0, native returned success with zero_weight 0.976 and mean 1e-4 here;
    the floor must lie below p0 and the mean (force balance) hold to rtol."""
    s = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    r = dp.pressure_distribution(s, E_star=8 / 3, mean_pressure=0.004, zeta=4, cutoff="smoothstep", p_c=0.02,
                                 backend="native", rtol=1e-6)
    assert r.success and r.diagnostics["p_floor"] < 0.004
    assert abs(r.mean + r.diagnostics["p_min"] * r.zero_weight - 0.004) <= 1e-6 * 0.004
    assert r.zero_weight < 1e-6  # f(p0) = 0.06: the start never gets near the floor 1e-6 p0 in tau = V/2


def test_a_diverging_refinement_stops_and_says_so():
    # a restoring drift with the paper's cutoff at a tiny p_c: below the floor, where 59 % of the probability lies,
    # the drift outweighs the diffusion f ~ (pi p/p_c)^2/2 and traps it in cells with |dt L_ii| up to 1e14, and the
    # finer grids lose accuracy: the shifted solves' round-off there (eps |dt L_ii|, growing 4x per halving).  Before
    # the flux form they also lost probability (1.5e-6 on 12208 cells) and the refinement diverged from rtol 1e-8
    # on (2.3e-8 -> 5.3e-8 -> 2.5e-7, and without the divergence rule on to 6.1e-6 on 65536 cells).  With the flux
    # form the mass holds to round-off and rtol 1e-8 converges (2.4e-9 on 890 cells); at 1e-9 the estimate still
    # grows (5.6e-10 -> 3.2e-9 -> 1.3e-8): the solve must stop at the second rise, fail, and say why
    p0, c = 0.272, 0.39
    f = dp.PressureFactor(dp.MuserCutoff(0.00252))
    drift = lambda p, tau: -c * (p - p0) / 2.0  # noqa: E731
    with pytest.warns(dp.ConvergenceWarning, match="refinement diverges"):
        r = dp.propagate(p0, 1.0, diffusivity=f, drift=drift, rtol=1e-9, backend="native")
    est = [e for _, e in r.diagnostics["history"]]
    assert not r.success and "refinement diverges" in r.message
    assert abs(r.diagnostics["mass_error"]) < 1e-12  # the flux form: 4.4e-16
    assert est[-1] > est[-2] > est[-3] and est[-1] > 10 * min(est) and max(r.diagnostics["levels"]) < 65536
    ok = dp.propagate(p0, 1.0, diffusivity=f, drift=drift, rtol=1e-8, backend="native")
    assert ok.success and ok.error_estimate <= 1e-8
    assert abs(ok.diagnostics["mass_error"]) < 1e-12  # 1.5e-6 without the flux form (the solve failed)


def test_probability_trapped_in_stiff_cells_is_conserved():
    """Random drift problem #196 of seed 6 (an audit of random drift problems): a restoring drift on the paper's
    cutoff at ``p_c/sqrt(V)`` = 0.001 traps 80 % of the probability far below the floor (``p_c`` 4.5e-7, the floor
    1.1e-10), in cells with ``|dt L_ii|`` up to 1.6e8.  The partial fractions lost ``eps |dt L_ii|`` of it per
    application: 1.3e-6 over the solve at rtol 1e-6 (the solve failed: "mass not conserved"), with alternating
    signs on the grids.  Written in flux form the mass is ``r(0)^224`` = 1 - 3.6e-10 of CF-12 (bound 1e-9), the
    answer converges at rtol 1e-6 and at 1e-8 (which failed too), and the two agree in the cdf within the former's
    rtol (measured 1.6e-8)."""
    spec = dp.SelfAffineSpectrum(0.5976223609769248, 0.0007669903939428206, 1.5707963267948966,
                                 C0=1892136.953053304)
    load, zeta, strength = 0.00011316189523441994, 0.5643729981053544, 0.2662625947557058
    V = float(dp.stress_variance(spec, E_star=8 / 3, mean_pressure=load, zeta=zeta))

    def drift(p, eta):
        D = dp.diffusivity_vs_magnification(spec, eta, E_star=8 / 3, mean_pressure=load, zeta=zeta)
        return -strength * D * (p - load) / (2.0 * np.sqrt(V))

    answers = [dp.pressure_distribution(spec, E_star=8 / 3, mean_pressure=load, zeta=zeta, cutoff="muser",
                                        p_c=4.450749399852294e-07, drift=drift, rtol=rtol) for rtol in (1e-6, 1e-8)]
    for r in answers:
        assert r.success, r.message
        assert abs(r.diagnostics["mass_error"]) < 1e-9
        assert r.zero_weight > 0.75  # the trapped probability, below the floor
    x = answers[1].edges
    assert np.max(np.abs(answers[0].cdf(x) - answers[1].cdf(x))) < 1e-6


def _seed7_problem_122():
    """Random drift problem #122 of seed 7 (an audit of random drift problems): a restoring drift on the smoothstep
    cutoff at ``p_c/sqrt(V)`` 0.009, ``p0/sqrt(V)`` 0.005; ``solve(rtol)`` returns the native answer."""
    spec = dp.SelfAffineSpectrum(0.8712260578507987, 0.0015339807878856412, 1.5707963267948966,
                                 C0=165380.1678226687)
    load, zeta, strength = 2.436587179424186e-05, 0.001166329992459077, 0.4111836988754969
    V = float(dp.stress_variance(spec, E_star=8 / 3, mean_pressure=load, zeta=zeta))

    def drift(p, eta):
        D = dp.diffusivity_vs_magnification(spec, eta, E_star=8 / 3, mean_pressure=load, zeta=zeta)
        return -strength * D * (p - load) / (2.0 * np.sqrt(V))

    def solve(rtol):
        return dp.pressure_distribution(spec, E_star=8 / 3, mean_pressure=load, zeta=zeta, cutoff="smoothstep",
                                        p_c=4.202856982669143e-05, drift=drift, rtol=rtol)

    return solve


def test_an_unstable_grid_fails_clearly(monkeypatch):
    """Problem #122 (:func:`_seed7_problem_122`) with the drift's central face value everywhere (the operator before
    the upwinding weight; a closure's drift keeps it).  Far below the floor the drift dominates the vanishing
    diffusion (cell Peclet numbers above 2 on half the faces), the central operator's spectrum leaves the negative
    real axis, and on fine grids the rational approximation amplifies a mode: at rtol 1e-8 the 5760-cell grid's
    states summed to 2e3 in absolute value (the solve reported an estimate of 1.5e3 and a mass 1.3e3 off), at rtol
    1e-7 the 10168-cell grid reached 1e237 and the refinement raised a ValueError on a NaN.  Such a grid is no
    result: the solve stops with success False and says why, every number finite."""
    from diffusion_pr.fokker_planck import stages

    monkeypatch.setattr(stages, "_fitted_stages", lambda prep, coef: np.zeros(coef["has_b"].size, dtype=bool))
    with pytest.warns(dp.ConvergenceWarning, match="unstable"):
        bad = _seed7_problem_122()(1e-8)
    assert not bad.success and "exponential integration is unstable on the 5760-cell grid" in bad.message
    assert np.all(np.isfinite(bad.density)) and np.isfinite(bad.error_estimate)


def test_a_dominating_drift_keeps_the_spectrum_real():
    """Problem #122 (:func:`_seed7_problem_122`) as the user solves it: the drift's upwinding weight where the cell
    Peclet number exceeds 2 (operator.fitted_weight) keeps the off-diagonal entries non-negative, the spectrum real,
    and the refinement stable.  It solves at rtol 1e-6 and 1e-7 (with the central value: unstable at 1e-7 and 1e-8,
    the test above), the mass is conserved, and the rtol-1e-6 answer is within its rtol of the rtol-1e-7 one in L1
    and within 3x its own estimate plus the oracle's (measured: 1.0e-7 against an estimate of 2.2e-7, against the
    rtol-1e-8 answer; the oracle's estimate 7e-9)."""
    solve = _seed7_problem_122()
    answer, oracle = solve(1e-6), solve(1e-7)
    for r in (answer, oracle):
        assert r.success and abs(r.diagnostics["mass_error"]) < 1e-9
    x = np.concatenate(([0.0], answer.edges))  # the audit's L1: zero weight and cells
    l1 = float(abs(answer.zero_weight - oracle.zero_weight)
               + np.sum(np.abs(np.diff(answer.cdf(x))[1:] - np.diff(oracle.cdf(x))[1:])))
    assert l1 <= 1e-6
    assert l1 <= 3 * answer.error_estimate + oracle.error_estimate
