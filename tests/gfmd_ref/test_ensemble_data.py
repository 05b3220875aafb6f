"""Bundled ensembles: complete, converged, consistent with their parameters and with
the independently generated reference seeds of diffusion_pr/data."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gfmd_ref import bundled_ensemble
from gfmd_ref.ensemble.data import BUNDLE_LEVELS
from gfmd_ref.ensemble.stats import noise_floor

FIG1_WALLS = [None, 0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0]
MIN_SEEDS = 32


@pytest.fixture(scope="module")
def fig1():
    return bundled_ensemble("fig1_n1024")


def test_fig1_bundle_complete_and_converged(fig1):
    assert fig1.zetas == FIG1_WALLS
    seeds = None
    for z in FIG1_WALLS:
        g = fig1.group("hard" if z is None else z)
        assert g.n_excluded == 0 and g.n_seeds >= MIN_SEEDS
        assert g.n == 1024 and g.mean_pressure == 0.004
        seeds = seeds or g.seeds
        assert g.seeds == seeds  # every wall on the same surfaces
        assert seeds == list(range(1, len(seeds) + 1))
    for r in fig1:
        assert r.provenance["residual"] < 1e-6 and r.params["tol"] == 1e-6
        assert r.E_star == pytest.approx(8 / 3, rel=1e-15)
        np.testing.assert_array_equal(r.levels, BUNDLE_LEVELS)
        assert np.all(np.diff(r.quantiles) >= 0)
        # load control: the field's mean is p0 to the solver tolerance
        assert r.mean == pytest.approx(0.004, rel=1e-6)
        # the stored quantile function integrates to the mean (trapezoid over levels; coarse in the tail)
        assert np.trapezoid(r.quantiles, r.levels) == pytest.approx(r.mean, rel=0.02)


def test_fig1_bundle_surfaces_are_the_fig1_surfaces(fig1):
    """Spectrum oracle: the Fig. 1 generator fixes the spectral rms slope to 0.031 and
    keeps wavelengths L ... L/32."""
    for r in fig1.select(wall="hard"):
        q, pw = r.spectrum_q, r.spectrum_power
        assert math.sqrt(float(np.sum(q**2 * pw))) == pytest.approx(0.031, rel=1e-10)
        assert q[0] == pytest.approx(2 * np.pi / 1024) and q[-1] <= 32 * 2 * np.pi / 1024 * (1 + 1e-12)


@pytest.mark.parametrize("wall", ["hard", 0.001, 0.25, 4.0])
def test_fig1_bundle_agrees_with_independent_reference_seeds(fig1, wall):
    """diffusion_pr/data holds seeds 1 and 2 made by another command and code version
    (diffusion-pr make-reference, git 5d3793b, tol 1e-6): the same solutions to within
    the solver tolerance: contact fraction to 1e-3 relative, CDF to one level step."""
    from diffusion_pr.jobs.reference_data import case_name, load_reference

    for seed in (1, 2):
        ref = load_reference(case_name(None if wall == "hard" else wall, seed))
        rec = fig1.select(wall=wall, seeds=[seed])[0]
        assert rec.contact_fraction == pytest.approx(ref.provenance["contact_fraction"], rel=1e-3)
        hq = ref.histogram.quantiles
        x = hq[(hq >= 0.004 / 20)]
        ref_cdf = np.interp(x, hq, ref.histogram.quantile_levels)
        assert np.max(np.abs(rec.cdf(x) - ref_cdf)) < 2e-3


def test_fig1_noise_floor_scales_as_inverse_sqrt_n(fig1):
    """The measured noise floor: K(N) ~ 0.037/sqrt(N) at large zeta. The split-half
    estimate must fall like 1/sqrt(N) (ratio K(1)/K(N_max) = sqrt(N_max) within
    sampling error) with a coefficient of that size."""
    nf = noise_floor(fig1.group(4.0), repeats=100)
    assert nf.sizes[-1] >= 8
    r = nf.k_noise[0] / nf.k_noise[-1]
    assert 0.6 * np.sqrt(nf.sizes[-1]) < r < 1.5 * np.sqrt(nf.sizes[-1])
    assert 0.02 < nf.coefficient < 0.06


def test_offscene_bundle():
    e = bundled_ensemble("offscene_n512")
    assert e.zetas == [None, 0.01, 0.1, 0.5, 2.0]
    for g in e.groups():
        assert g.n_seeds == 16 and g.n_excluded == 0 and g.n == 512 and g.mean_pressure == 0.005
        assert g.E_star == 1.0
    for r in e:
        assert r.params["surface"] == dict(kind="self_affine", hurst=0.7, rms_slope=0.05, n_waves=32)
        assert r.mean == pytest.approx(0.005, rel=1e-6)
        q, pw = r.spectrum_q, r.spectrum_power
        assert math.sqrt(float(np.sum(q**2 * pw))) == pytest.approx(0.05, rel=1e-10)
    # hard wall: contact grows as the wall softens; soft walls are fully "in contact" at zeta = 2
    cf = [np.mean([r.contact_fraction for r in g]) for g in e.groups()]
    assert all(a < b for a, b in zip(cf[:-1], cf[1:])) and cf[-1] == 1.0


def test_bundled_ensemble_rejects_unknown_name():
    with pytest.raises(ValueError, match="fig1_n1024"):
        bundled_ensemble("fig2")


def test_group_by_zeta_is_group_by_wall():
    """``group(zeta=z)`` selects exactly the records of ``group(z)`` (and ``zeta=None``
    the hard wall); giving both is refused."""
    import gfmd_ref

    e = gfmd_ref.bundled_ensemble("fig1_n1024")
    for z in (None, 0.25, 4.0):
        by_wall = e.group("hard" if z is None else z)
        by_zeta = e.group(zeta=z)
        assert [(r.seed, r.zeta) for r in by_zeta.records] == [(r.seed, r.zeta) for r in by_wall.records]
        assert all(r.zeta == z for r in by_zeta.records)
    assert [r.seed for r in e.group().records] == [r.seed for r in e.group("hard").records]
    with pytest.raises(ValueError, match="not both"):
        e.group(0.25, zeta=0.25)
