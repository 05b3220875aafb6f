"""Ensemble reductions and diffusion_pr.compare.compare_ensemble on synthetic
ensembles whose distribution is known exactly (i.i.d. exponential pressures)."""
from __future__ import annotations

import numpy as np
import pytest

from gfmd_ref.ensemble.stats import (
    bootstrap_cdf_band,
    bootstrap_density_band,
    cdf_grid,
    finite_size_table,
    kolmogorov,
    noise_floor,
    pooled_cdf,
)
from gfmd_ref.ensemble.store import Ensemble, EnsembleRecord, case_key, reduce_pressure_field

P0 = 0.004
M = 4096  # values per synthetic seed
S = 16


def _record(p, seed, *, zeta=None, n=64, converged=True):
    params = dict(n=n, length=float(n), seed=seed, zeta=zeta, mean_pressure=P0, E_star=1.0,
                  surface=dict(kind="synthetic"), tol=1e-6, method="auto")
    red = reduce_pressure_field(p, mean_pressure=P0, zeta=zeta)
    prov = dict(converged=converged, residual=1e-7, iterations=1, wall_time=0.0, source="synthetic")
    keep = {k: red[k] for k in ("levels", "quantiles", "mean", "variance", "third_central", "sd", "skewness",
                                "contact_fraction", "contact_threshold", "zero_weight")}
    return EnsembleRecord(key=case_key(params), params=params, provenance=prov, **keep)


@pytest.fixture(scope="module")
def expo():
    rng = np.random.default_rng(11)
    samples = [rng.exponential(P0, M) for _ in range(S)]
    return samples, [_record(s, i + 1) for i, s in enumerate(samples)]


class Expo:
    """Exact exponential law of mean P0, with an optional atom at 0."""

    def __init__(self, atom=0.0):
        self.atom = atom

    def cdf(self, p):
        p = np.asarray(p, float)
        return np.where(p < 0, 0.0, self.atom + (1 - self.atom) * (1 - np.exp(-np.maximum(p, 0) / P0)))


class Pooled:
    def __init__(self, recs):
        self.recs = recs

    def cdf(self, p):
        return pooled_cdf(self.recs, np.asarray(p, float))


def test_kolmogorov_is_exact_supremum(expo):
    _, recs = expo
    a, b = recs[:8], recs[8:]
    k = kolmogorov(a, b)
    dense = np.linspace(P0 / 20, 12 * P0, 200001)
    brute = np.max(np.abs(pooled_cdf(a, dense) - pooled_cdf(b, dense)))
    assert brute <= k + 1e-12  # the knot grid finds the supremum
    assert k - brute < 2e-4  # and nothing beyond it (dense grid resolution)
    x = cdf_grid(recs)
    assert x[0] == pytest.approx(P0 / 20) and np.all(np.diff(x) > 0)


def test_record_cdf_inverts_the_quantiles(expo):
    _, recs = expo
    r = recs[0]
    inner = (r.quantiles > r.quantiles[0]) & (r.quantiles < r.quantiles[-1])
    np.testing.assert_allclose(r.cdf(r.quantiles[inner]), r.levels[inner], atol=1e-12)
    # the hard-wall delta peak: F(0) = zero weight (right-continuous), to one level step
    rng = np.random.default_rng(4)
    hard = _record(np.where(rng.random(M) < 0.37, 0.0, rng.exponential(P0, M)), 1)
    assert float(hard.cdf(0.0)) == pytest.approx(hard.zero_weight, abs=1 / 2048)
    assert float(hard.cdf(-1e-30)) == 0.0


def test_noise_floor_matches_iid_theory():
    """For i.i.d. values the Kolmogorov distance of a pool of N seeds (N m values)
    from the true law has mean 0.8687/sqrt(N m) asymptotically (Kolmogorov
    distribution mean sqrt(pi/2) ln 2), a few per cent less at m = 1024 and over
    p >= p0/20 (measured 0.85-0.97 x over three ensembles of 64 seeds); the
    split-half estimator must recover it (a missing 1/sqrt 2 gives 1.3 x)."""
    rng = np.random.default_rng(12)
    m = 1024
    recs = [_record(rng.exponential(P0, m), i + 1) for i in range(64)]
    nf = noise_floor(recs, repeats=100)
    assert nf.sizes.tolist() == [1, 2, 4, 8, 16, 32]
    ratio = nf.k_noise / (0.8687 / np.sqrt(nf.sizes * m))
    assert np.all((ratio > 0.75) & (ratio < 1.1)), ratio
    assert nf.coefficient * np.sqrt(m) == pytest.approx(0.8687, rel=0.2)
    assert nf.k_noise_full == pytest.approx(nf.coefficient / np.sqrt(64))
    with pytest.raises(ValueError, match="sizes"):
        noise_floor(recs, sizes=[33])


def test_bootstrap_bands_cover_the_truth(expo):
    _, recs = expo
    p = np.linspace(P0 / 10, 5 * P0, 40)
    F, lo, hi = bootstrap_cdf_band(recs, p, n_boot=300)
    assert np.all(lo <= F + 1e-15) and np.all(F <= hi + 1e-15)
    inside = np.mean((Expo().cdf(p) >= lo) & (Expo().cdf(p) <= hi))
    assert inside >= 0.8  # 95 % pointwise bands; the truth is inside almost everywhere
    edges = np.linspace(0, 5 * P0, 21)
    d, dlo, dhi = bootstrap_density_band(recs, edges, n_boot=300)
    true = np.diff(Expo().cdf(edges)) / np.diff(edges)
    assert np.mean((true >= dlo) & (true <= dhi)) >= 0.8


def test_compare_ensemble_oracles(expo):
    from diffusion_pr.compare import compare_ensemble

    samples, recs = expo
    # theory == the pool itself: K and L1 vanish; per-seed K is each seed's distance from the pool
    c0 = compare_ensemble(Pooled(recs), recs, n_boot=50, n_split=20)
    assert c0.kolmogorov < 1e-12 and c0.l1 < 1e-12
    # theory == one seed: that seed's K vanishes
    c1 = compare_ensemble(Pooled(recs[:1]), recs, n_boot=50, n_split=20)
    assert c1.kolmogorov_per_seed[0] < 1e-12 and c1.kolmogorov_per_seed[1:].min() > 1e-3
    # the true law: K is of the size of the ensemble's own noise, which is calibrated
    c = compare_ensemble(Expo(), recs, n_boot=400, n_split=200)
    iid = 0.8687 / np.sqrt(S * M)
    assert c.noise_bootstrap == pytest.approx(iid, rel=0.35)
    assert c.noise_split == pytest.approx(iid, rel=0.35)
    assert c.kolmogorov < 4 * iid
    assert c.p_min == pytest.approx(P0 / 20)
    # moments from the CDF (no .moment): exponential sd = p0, skewness 2
    assert c.sd_theory == pytest.approx(P0, rel=2e-3) and c.skewness_theory == pytest.approx(2.0, rel=2e-2)
    # pooled moments from per-seed moments equal those of the concatenated values
    allv = np.concatenate(samples)
    cc = allv - allv.mean()
    assert c.sd_pool == pytest.approx(allv.std(), rel=1e-10)
    assert c.skewness_pool == pytest.approx(np.mean(cc**3) / allv.std() ** 3, rel=1e-9)
    assert c.sd_gfmd == pytest.approx(np.mean([s.std() for s in samples]), rel=1e-12)
    # a shifted theory is further away by about the shift of the CDF
    c_far = compare_ensemble(Expo(atom=0.05), recs, n_boot=50, n_split=20)
    assert c_far.kolmogorov == pytest.approx(0.05, abs=4 * iid + 1e-3)
    assert "p >= " in c.summary()
    # the plotted band holds the pool and (almost everywhere) the truth
    assert np.all((c.cdf_lo <= c.cdf_pool + 1e-15) & (c.cdf_pool <= c.cdf_hi + 1e-15))
    assert np.mean((c.cdf_theory >= c.cdf_lo) & (c.cdf_theory <= c.cdf_hi)) > 0.8


def test_compare_ensemble_contact_fraction_uses_gfmd_threshold():
    from diffusion_pr.compare import compare_ensemble

    rng = np.random.default_rng(5)
    hard = [_record(np.where(rng.random(M) < 0.4, 0.0, rng.exponential(P0, M)), s) for s in range(1, 5)]
    c = compare_ensemble(Expo(atom=0.4), hard, n_boot=20, n_split=10)
    assert c.threshold == 0.0
    assert c.contact_fraction_theory == pytest.approx(0.6, abs=1e-12)
    assert c.contact_fraction_gfmd == pytest.approx(0.6, abs=0.02)
    soft = [_record(rng.exponential(P0, M), s, zeta=0.5) for s in range(1, 5)]
    cs = compare_ensemble(Expo(), soft, n_boot=20, n_split=10)
    thr = 0.01 * P0
    assert cs.threshold == pytest.approx(thr)
    assert cs.contact_fraction_theory == pytest.approx(np.exp(-0.01), rel=1e-12)
    assert cs.contact_fraction_gfmd == pytest.approx(np.exp(-0.01), abs=0.01)


def test_compare_ensemble_rejects_mixed_pools_and_counts_exclusions(expo):
    from diffusion_pr.compare import compare_ensemble

    _, recs = expo
    rng = np.random.default_rng(1)
    other = _record(rng.exponential(P0, M), 99, zeta=0.5)
    with pytest.raises(ValueError, match="mixes walls"):
        compare_ensemble(Expo(), recs[:3] + [other])
    bad = _record(rng.exponential(P0, M), 50, converged=False)
    ens = Ensemble(recs[:4] + [bad])
    g = ens.group("hard")
    assert g.n_seeds == 4 and g.n_excluded == 1
    c = compare_ensemble(Expo(), g, n_boot=20, n_split=10)
    assert c.n_seeds == 4 and c.n_excluded == 1
    with pytest.raises(ValueError, match="at least 2 converged"):
        compare_ensemble(Expo(), [recs[0], bad])


def test_finite_size_table_sees_a_resolution_effect():
    """Two 'grids' whose laws differ by a known CDF shift: K to the finest is that
    shift, well above the quoted noise; the finest grid's row is the reference."""
    rng = np.random.default_rng(2)
    coarse = [_record(rng.exponential(1.1 * P0, M), s, n=32) for s in range(1, 9)]
    fine = [_record(rng.exponential(P0, M), s, n=64) for s in range(1, 9)]
    rows = finite_size_table(Ensemble(coarse + fine), "hard")
    # exponential walls: the same physical zeta is zeta n / n_ref grid units
    soft = [_record(rng.exponential(P0, M), s, n=32, zeta=0.5) for s in range(1, 3)]
    soft += [_record(rng.exponential(P0, M), s, n=64, zeta=1.0) for s in range(1, 3)]
    soft += [_record(rng.exponential(P0, M), s, n=64, zeta=0.5) for s in range(1, 3)]
    srows = finite_size_table(Ensemble(soft), 1.0, n_ref=64)
    assert [(r["n"], r["seeds"]) for r in srows] == [(32, 2), (64, 2)]
    assert [r["n"] for r in rows] == [32, 64] and rows[1]["k_to_finest"] == 0.0
    x = np.linspace(P0 / 20, 10 * P0, 10001)
    shift = np.max(np.exp(-x / (1.1 * P0)) - np.exp(-x / P0))
    assert rows[0]["k_to_finest"] == pytest.approx(shift, abs=0.01)
    assert rows[0]["k_noise"] < shift / 3
    assert rows[0]["sd_over_p0"] == pytest.approx(1.1, rel=0.05)
