"""The paper's Fig. 1 claims and the closures, measured on GFMD ensembles.

Distances between a theory and GFMD are asserted only against pooled ensembles
(``gfmd_ref.bundled_ensemble``: compact per-seed quantiles), with tolerances
derived from the ensemble's own bootstrap noise
(:func:`diffusion_pr.compare.compare_ensemble`, K over ``p >= p0/20``); no test
asserts a single seed's K below its noise (about 0.07 at the 95th percentile).
Single-seed checks that remain (curvature, moments, fits, the gap-field mapping)
compare quantities far above that noise.  Numbers: ``docs/fig1.md``.
"""
from __future__ import annotations

import numpy as np
import pytest

import diffusion_pr as dp
from diffusion_pr.compare import compare, compare_ensemble, fit_cutoff_pressure, fit_tail_pressure, tail_curvatures
from diffusion_pr.jobs.reference_data import FIG1_SCENE, case_name, load_reference, paper_theory

E_STAR = FIG1_SCENE["E_star"]
P0 = FIG1_SCENE["mean_pressure"]
SEEDS = (1, 2)


@pytest.fixture(scope="module")
def runs():
    """(zeta, seed) -> (case, theory with the paper's cutoff and p_c, comparison)."""
    out = {}
    for seed in SEEDS:
        for zeta in (None, 0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0):
            case = load_reference(case_name(zeta, seed))
            theory = paper_theory(case)
            out[zeta, seed] = (case, theory, compare(theory, case.histogram))
    return out


def test_theory_solves_succeeded(runs):
    for (zeta, seed), (_, theory, _) in runs.items():
        assert theory.success, (zeta, seed, theory.message)
        assert theory.mass == pytest.approx(1.0, abs=1e-5)
        assert theory.mean == pytest.approx(P0, rel=1e-4)


@pytest.mark.parametrize("seed", SEEDS)
def test_g1_variance_matches_gfmd_at_large_zeta(runs, seed):
    """Claim: the second-order cumulant (G1) captures the stress fluctuations.

    Measured sd_sim / sqrt(V_G1) at zeta = 0.25 ... 4: 0.99-1.02 (seed 1),
    1.07-1.18 (seed 2; the realization's nonlinear terms, which vanish only on
    average, Eq. 5).  Persson's V0 would be off by a factor 6-60.
    """
    for zeta in (0.25, 0.5, 1.0, 2.0, 4.0):
        case, _, cmp = runs[zeta, seed]
        sd_sim = np.sqrt(cmp.moments_sim["variance"])
        v_g1 = float(dp.stress_variance(case.spectrum, E_star=E_STAR, mean_pressure=P0, zeta=zeta))
        v0 = float(dp.stress_variance(case.spectrum, E_star=E_STAR, mean_pressure=P0, zeta=0.0))
        assert 0.95 < sd_sim / np.sqrt(v_g1) < 1.25, (zeta, sd_sim / np.sqrt(v_g1))
        assert np.sqrt(v0) / sd_sim > 5.0


@pytest.mark.parametrize("seed", SEEDS)
def test_log_density_curvature_at_small_zeta(runs, seed):
    """Claim: 'at very small zeta the curvature of ln Pr is off by about 20 %'.

    Measured (p0 down two decades of the GFMD density): Persson against the
    hard wall 23-27 % (reproduced in the zeta -> 0 limit); the theory at
    zeta = 0.001 with the paper's p_c = 0.0068: 53-57 % (not 20 %).
    """
    c_sim, c_th, _ = tail_curvatures(runs[None, seed][1], runs[None, seed][0].histogram)
    assert 1.10 < c_th / c_sim < 1.40
    c_sim, c_th, _ = tail_curvatures(runs[0.001, seed][1], runs[0.001, seed][0].histogram)
    assert 1.35 < c_th / c_sim < 1.80


@pytest.mark.parametrize("seed", SEEDS)
def test_intermediate_zeta_tails_are_convex(runs, seed):
    """Why it degrades: at zeta = 0.1-0.25 GFMD's ln Pr is convex (exponential-like
    tail: the exponential wall maps Gaussian gaps to log-normal-like pressures),
    which a Gaussian-broadening theory cannot produce."""
    for zeta in (0.1, 0.25):
        c_sim, c_th, _ = tail_curvatures(runs[zeta, seed][1], runs[zeta, seed][0].histogram)
        assert c_sim > 0 > c_th, (zeta, c_sim, c_th)


def test_theory_tends_to_persson_as_zeta_vanishes(runs):
    """Claim: as zeta -> 0 the theory goes to Persson's.  V(zeta)/V0 -> 1:
    0.993 at 1e-4, 0.929 at 1e-3, 0.55 at 1e-2 (Eq. 10 on the surface's spectrum)."""
    spectrum = runs[0.001, 1][0].spectrum
    v = dp.stress_variance(spectrum, E_star=E_STAR, mean_pressure=P0, zeta=np.array([0.0, 1e-4, 1e-3, 1e-2]))
    ratio = v / v[0]
    assert np.all(np.diff(ratio) < 0)
    assert ratio[1] > 0.99 and 0.90 < ratio[2] < 0.95
    # with the sharp cutoff, zeta = 1e-5 is indistinguishable from Persson
    persson = runs[None, 1][1]
    tiny = dp.pressure_distribution(spectrum, E_star=E_STAR, mean_pressure=P0, zeta=1e-5, cutoff="sharp")
    assert abs(tiny.zero_weight - persson.zero_weight) < 1e-3


@pytest.mark.parametrize("seed", SEEDS)
def test_hard_wall_contact_area_exceeds_persson(runs, seed):
    """Independent numbers (Hyun et al. 2004; Prodanov et al. 2014): GFMD's
    contact area exceeds Persson's, kappa ~ 2 against sqrt(8/pi) = 1.60.
    Measured: a_GFMD / a_Persson = 1.38 (seed 1), 1.32 (seed 2); kappa = 2.19, 2.10."""
    case, persson, cmp = runs[None, seed]
    gbar = case.spectrum.rms_slope
    kappa_sim = cmp.contact_fraction_sim * E_STAR * gbar / P0
    kappa_persson = cmp.contact_fraction_theory * E_STAR * gbar / P0
    assert 1.25 < cmp.contact_fraction_sim / cmp.contact_fraction_theory < 1.50
    assert 1.9 < kappa_sim < 2.4
    # Persson's small-load limit: a_r -> sqrt(8/pi) p0/(E* gbar); here p0/sqrt(V0)
    # = 0.097, so the limit holds to O((p0/sqrt V0)^2) ~ 0.3 %
    assert kappa_persson == pytest.approx(np.sqrt(8 / np.pi), rel=5e-3)


def test_fitted_cutoff_pressure_at_zeta_0_01():
    """p_c fitted by least squares on ln Pr, against the paper's 0.0082.

    Measured (seed 1): Müser's literal cutoff 0.0167 (2.0 x the paper), raised
    cosine 0.0111; the raised cosine fits best (objective 0.018 against 0.038).
    (No assertion on this single seed's K: its noise is about 0.07.)
    """
    case = load_reference(case_name(0.01, 1))
    hist = case.histogram.rebinned(2)
    fits = {cut: fit_cutoff_pressure(hist, case.spectrum, E_star=E_STAR, mean_pressure=P0, zeta=0.01, cutoff=cut,
                                     rtol=1e-4) for cut in ("muser", "raised_cosine")}
    assert all(f.success for f in fits.values())
    assert 1.5 < fits["muser"].p_c / 0.0082 < 2.5
    assert fits["raised_cosine"].objective < fits["muser"].objective


def test_exponential_tail_fits_a_surface_that_is_not_coloured_noise():
    """Claim: non-Gaussian tails of Pr(p) come from surfaces that are not
    coloured noise and are rationalized by D growing with p.

    Measured on the skewed surface (hard wall): Persson's Gaussian theory
    Kolmogorov 0.031, L1 0.083; the linear-tail variant with fitted p_t
    (about 0.018) 0.003 and 0.010.  On the coloured-noise surface the same fit
    gains nothing (p_t runs to the bracket edge).
    """
    skew = load_reference("fig1-skewed_n1024_hard_s1")
    hist = skew.histogram.rebinned(4)
    gauss = compare(paper_theory(skew), hist)
    p_t, _ = fit_tail_pressure(hist, skew.spectrum, E_star=E_STAR, mean_pressure=P0, tail="linear", rtol=1e-4)
    tail = compare(dp.pressure_distribution(skew.spectrum, E_star=E_STAR, mean_pressure=P0, cutoff="sharp",
                                            tail="linear", p_t=p_t, rtol=1e-4), hist)
    assert tail.kolmogorov < gauss.kolmogorov / 5.0
    assert tail.l1 < gauss.l1 / 4.0
    assert 0.005 < p_t < 0.05
    # the contact fraction follows: 0.044 against GFMD's 0.047 (Persson: 0.077)
    assert abs(tail.contact_fraction_theory - tail.contact_fraction_sim) < 0.01

    plain = load_reference(case_name(None, 1))
    hist = plain.histogram.rebinned(4)
    gauss = compare(paper_theory(plain), hist)
    p_t, _ = fit_tail_pressure(hist, plain.spectrum, E_star=E_STAR, mean_pressure=P0, tail="linear", rtol=1e-4)
    tail = compare(dp.pressure_distribution(plain.spectrum, E_star=E_STAR, mean_pressure=P0, cutoff="sharp",
                                            tail="linear", p_t=p_t, rtol=1e-4), hist)
    assert tail.kolmogorov > 0.8 * gauss.kolmogorov


@pytest.mark.parametrize("seed", SEEDS)
def test_first_three_moments(runs, seed):
    """Mean, variance and skewness of theory and GFMD (delta peaks included).

    Mean: both conserve p0 (force balance; GFMD to its load tolerance, theory
    to rtol).  Skewness: at zeta >= 0.25 GFMD is skewed (0.3-3.8) while the
    theory is nearly symmetric (-0.12 ... 1.2): the measured gap is 0.33-2.6,
    the shape misfit behind the Kolmogorov distances above.  Hard wall:
    Persson's skewness 4.48 against GFMD's 4.05 / 4.31.
    """
    for zeta in (None, 0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0):
        m_sim, m_th = runs[zeta, seed][2].moments_sim, runs[zeta, seed][2].moments_theory
        assert m_sim["mean"] == pytest.approx(P0, rel=1e-6)
        assert m_th["mean"] == pytest.approx(P0, rel=1e-4)
        skew_sim = m_sim["third_central"] / m_sim["variance"] ** 1.5
        skew_th = m_th["third_central"] / m_th["variance"] ** 1.5
        if zeta is None:
            assert abs(skew_th - skew_sim) < 0.6
        elif zeta >= 0.25:
            assert skew_sim - skew_th > 0.25, (zeta, skew_sim, skew_th)
            # variance: within 25 % at zeta >= 1, where the cutoff does not bite
            if zeta >= 1.0:
                assert m_th["variance"] / m_sim["variance"] == pytest.approx(1.0, abs=0.3)


# ----------------------------------------------------------------------------- ensembles
def _mean_spectrum(group):
    """Average power per lattice shell over the group's seeds (same lattice): the expected
    spectrum of the pooled ensemble (docs/closures.md)."""
    from diffusion_pr.spectra import DiscreteSpectrum

    recs = list(group.records)
    qs = np.unique(np.concatenate([np.asarray(r.spectrum_q, float) for r in recs]))
    power = np.zeros(qs.size)
    mult = np.ones(qs.size, dtype=np.int64)
    for r in recs:
        idx = np.searchsorted(qs, np.asarray(r.spectrum_q, float))
        power[idx] += np.asarray(r.spectrum_power, float)
        mult[idx] = np.maximum(mult[idx], np.asarray(r.spectrum_multiplicity))
    return DiscreteSpectrum(qs, power / len(recs), mult, float(recs[0].length))


def _ensemble_compare(name, zeta, closure, *, paper_pc=False, n_cells=800):
    from gfmd_ref import bundled_ensemble

    from oracles.closure_reference import reference_distribution

    from diffusion_pr.paper import cutoff_pressure

    group = bundled_ensemble(name).group(zeta)
    rec = group.records[0]
    E, p0 = float(rec.E_star), float(rec.mean_pressure)
    kw = {}
    if closure.startswith("local"):
        # reference solver: K error ~5e-4 (800 cells) / 1e-3 (400), far below the targets' margins
        kw = {"n_cells": n_cells, "n_steps": n_cells}
    elif closure == "second_order" and paper_pc and zeta is not None:
        kw = {"cutoff": "muser", "p_c": cutoff_pressure(zeta), "rtol": 1e-5}
    solve = reference_distribution if closure.startswith("local") else dp.pressure_distribution
    th = solve(_mean_spectrum(group), E_star=E, mean_pressure=p0, zeta=0.0 if zeta is None else zeta,
               closure=closure, **kw)
    return compare_ensemble(th, group, n_boot=200, n_split=50)


#: off-scene ensemble (512^2, H 0.7, slope 0.05, E* 1, p0 0.005, 16 seeds): measured K of
#: local_g1_balanced against the pooled ensemble and the bootstrap noise beside it
OFFSCENE_BALANCED = {None: (0.0390, 0.0009), 0.01: (0.0621, 0.0015), 0.1: (0.0472, 0.0061),
                     0.5: (0.0028, 0.0116), 2.0: (0.0070, 0.0128)}
TARGETS = {None: 0.04, 0.01: 0.04, 0.1: 0.05, 0.5: 0.025, 2.0: 0.01}


@pytest.mark.parametrize("zeta", [None, 0.01, 0.1, 0.5, 2.0])
def test_offscene_balanced_closure_against_the_pooled_ensemble(zeta):
    """Off the paper's scene, no fitted number: local_g1_balanced meets the K targets
    (TARGETS: 0.04 at the hard wall and zeta = 0.01, 0.05 at 0.1, 0.025 at 0.5, 0.01 at 2)
    at zeta = 0.1, 0.5, 2 and the hard wall (where it is Persson: 0.039 against 0.04), and
    misses at zeta = 0.01 (0.062).  Tolerance: 3 x the ensemble's bootstrap noise around
    the measured value (plus 1e-3 for the reference solver at 800 cells)."""
    c = _ensemble_compare("offscene_n512", zeta, "local_g1_balanced")
    k_meas, noise = OFFSCENE_BALANCED[zeta]
    assert c.noise_bootstrap == pytest.approx(noise, rel=0.5)
    assert abs(c.kolmogorov - k_meas) < 3 * c.noise_bootstrap + 1e-3
    if zeta == 0.01:
        assert c.kolmogorov > TARGETS[zeta] + 3 * c.noise_bootstrap  # the miss is real
    else:
        assert c.kolmogorov < TARGETS[zeta] + 2 * c.noise_bootstrap


def test_offscene_second_order_is_far_worse_at_intermediate_zeta():
    """The parameter-free second order (sharp cutoff) at zeta = 0.5 off-scene: K = 0.33,
    a hundred times the balanced closure's 0.003 and 30x the noise."""
    so = _ensemble_compare("offscene_n512", 0.5, "second_order")
    bal = _ensemble_compare("offscene_n512", 0.5, "local_g1_balanced")
    assert so.kolmogorov > 0.25
    assert so.kolmogorov - bal.kolmogorov > 10 * so.noise_bootstrap
    # skewness: GFMD 2.3 (pool), balanced 2.2, second order 0.8
    assert abs(bal.skewness_theory - bal.skewness_pool) < 0.3 < abs(so.skewness_theory - so.skewness_pool)


# ----------------------------------------------------------------------------- the Fig. 1 ensemble
#: the targets for K against the pooled ensemble, per wall (no fitted parameter)
FIG1_TARGETS = {None: 0.04, 0.001: 0.04, 0.01: 0.04, 0.1: 0.05, 0.25: 0.025, 0.5: 0.025, 1.0: 0.01, 2.0: 0.01,
                4.0: 0.01}


@pytest.mark.slow
@pytest.mark.parametrize("zeta", [None, 0.001, 0.25, 0.5, 1.0, 4.0])
def test_fig1_balanced_closure_meets_the_targets(zeta):
    """local_g1_balanced against the bundled Fig. 1 ensemble (K over p >= p0/20): within
    target + 2 x the bootstrap noise.  Measured on 16 seeds (docs/fig1.md): 0.027 (hard wall
    = Persson), 0.033 (0.001), 0.021 (0.25), 0.005 (0.5), 0.002 (1), 0.0025 (4)."""
    c = _ensemble_compare("fig1_n1024", zeta, "local_g1_balanced", n_cells=400)
    assert c.kolmogorov < FIG1_TARGETS[zeta] + 2 * c.noise_bootstrap, (c.kolmogorov, c.noise_bootstrap)


@pytest.mark.parametrize("zeta", [0.01, 0.1])
def test_fig1_balanced_closure_misses_the_targets_at_small_zeta(zeta):
    """Where the targets are missed, the test says so: zeta = 0.01 (K about 0.06 against
    0.04; noise 0.0007) and 0.1 (0.077 against 0.05; noise 0.005), beyond 2 x the noise."""
    c = _ensemble_compare("fig1_n1024", zeta, "local_g1_balanced", n_cells=400)
    assert c.kolmogorov > FIG1_TARGETS[zeta] + 2 * c.noise_bootstrap, (c.kolmogorov, c.noise_bootstrap)
    assert c.kolmogorov < 0.1


def test_fig1_second_order_is_not_flawless_at_large_zeta():
    """Claim: 'for large zeta theory and simulation agree flawlessly'.  Not so on the
    ensemble: at zeta = 4 the paper's second order misses by K = 0.031, 3x the noise (0.009)
    and 12x the balanced closure's 0.0025; its skewness (-0.03) is not GFMD's (0.50)."""
    so = _ensemble_compare("fig1_n1024", 4.0, "second_order", paper_pc=True)
    bal = _ensemble_compare("fig1_n1024", 4.0, "local_g1_balanced", n_cells=400)
    assert so.kolmogorov > 3 * so.noise_bootstrap
    assert so.kolmogorov > 3 * bal.kolmogorov
    assert abs(so.skewness_theory) < 0.1 and so.skewness_pool > 0.3
    assert abs(bal.skewness_theory - bal.skewness_pool) < 0.1


def test_fig1_agreement_degrades_at_intermediate_zeta():
    """Claim: agreement degrades at intermediate zeta.  Reproduced on the ensemble: the
    paper's second order K = 0.031 at zeta = 0.001, 0.35 at 0.25, 0.031 at 4."""
    k = {z: _ensemble_compare("fig1_n1024", z, "second_order", paper_pc=True).kolmogorov for z in (0.001, 0.25, 4.0)}
    assert k[0.25] > 5 * k[0.001] and k[0.25] > 5 * k[4.0]
    assert k[0.25] > 0.25


def test_fig1_hard_wall_contact_area_exceeds_persson_on_the_ensemble():
    """Independent numbers (Hyun et al. 2004; Prodanov et al. 2014): kappa about 2 against
    Persson's 1.60.  Pooled GFMD contact fraction 0.1044 against Persson's 0.0771 (16
    seeds): ratio 1.35, kappa 2.16; the seed-to-seed sd of the contact fraction is about 1 %."""
    c = _ensemble_compare("fig1_n1024", None, "second_order")
    gbar = 0.031
    assert 1.25 < c.contact_fraction_gfmd / c.contact_fraction_theory < 1.5
    assert 1.9 < c.contact_fraction_gfmd * E_STAR * gbar / P0 < 2.4
    assert c.contact_fraction_gfmd_sd < 0.05 * c.contact_fraction_gfmd


@pytest.mark.parametrize("name, zeta", [("fig1_n1024", z) for z in (None, 0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)]
                         + [("offscene_n512", z) for z in (None, 0.01, 0.1, 0.5, 2.0)])
def test_shell_balanced_closure_meets_every_target(name, zeta):
    """The closure local_g1_shell_balanced (partition at each shell's q_k) meets
    the K targets (FIG1_TARGETS) at every wall of both ensembles, no fitted number: K within target +
    2 x the bootstrap noise.  Measured (16 seeds each): Fig. 1 0.027 (hard), 0.017 (0.001),
    0.027 (0.01), 0.034 (0.1), 0.014 (0.25), 0.004 (0.5), 0.002 (1, 2), 0.0025 (4);
    off-scene 0.039 (hard), 0.032 (0.01), 0.047 (0.1), 0.015 (0.5), 0.0075 (2)."""
    c = _ensemble_compare(name, zeta, "local_g1_shell_balanced", n_cells=400)
    assert c.kolmogorov < FIG1_TARGETS[zeta] + 2 * c.noise_bootstrap, (c.kolmogorov, c.noise_bootstrap)
