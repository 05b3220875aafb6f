"""Theory against a GFMD ensemble (many seeds): :func:`compare_ensemble`.

Records are duck-typed: anything with ``levels``, ``quantiles`` (pressures at ``levels``), ``seed``, ``mean_pressure``,
``contact_fraction``, ``contact_threshold``, ``mean``, ``variance``, ``third_central``, ``converged``
(:class:`gfmd_ref.ensemble_store.EnsembleRecord` has them); :mod:`diffusion_pr` does not import :mod:`gfmd_ref`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
from numpy.typing import ArrayLike

from .distances import Array


def _record_cdf(rec: Any, p: Array) -> Array:
    """Empirical CDF of one record, linear between its quantiles, right-continuous at ties."""
    q = np.asarray(rec.quantiles, dtype=float)
    lev = np.asarray(rec.levels, dtype=float)
    idx = np.searchsorted(q, p, side="right")
    lo = np.clip(idx - 1, 0, q.size - 1)
    hi = np.clip(idx, 0, q.size - 1)
    ql, qh = q[lo], q[hi]
    gap = np.where(qh > ql, qh - ql, 1.0)
    t = np.where(qh > ql, (p - ql) / gap, 0.0)
    out = lev[lo] + np.clip(t, 0.0, 1.0) * (lev[hi] - lev[lo])
    return np.where(p < q[0], 0.0, np.where(p >= q[-1], 1.0, out))


def _theory_moments(theory: Any, p_hi: float) -> tuple[float, float, float]:
    """Mean, variance, third central moment of a theory (its own ``moment`` if it has
    one, else from its CDF on a fine grid up to the pressure where ``F = 1 - 1e-9``)."""
    if hasattr(theory, "moment") and hasattr(theory, "mean"):
        return (float(theory.mean), float(theory.moment(2, central=True)), float(theory.moment(3, central=True)))
    top = float(p_hi)
    while float(np.asarray(theory.cdf(top))) < 1.0 - 1e-9 and top < 1e6 * p_hi:
        top *= 2.0
    x = np.linspace(0.0, top, 200001)
    F = np.asarray(theory.cdf(x), dtype=float)
    m = np.diff(np.concatenate(([0.0], F)))
    c = np.concatenate(([0.0], 0.5 * (x[1:] + x[:-1])))
    mean = float(np.sum(m * c))
    return mean, float(np.sum(m * (c - mean) ** 2)), float(np.sum(m * (c - mean) ** 3))


@dataclass(frozen=True)
class EnsembleComparison:
    """A theory against a pooled GFMD ensemble, with the ensemble's own noise.

    Attributes
    ----------
    kolmogorov : float
        ``K = sup |F_theory - F_pool|`` over ``p >= p_min`` (dimensionless); the pool gives every seed the same area.
    kolmogorov_ci : (float, float)
        2.5 and 97.5 percentiles of ``K`` against bootstrap pools (seeds resampled).
    noise_bootstrap : float
        Median of ``sup |F_boot - F_pool|`` over bootstrap pools: the typical distance of the pool from the
        infinite-ensemble distribution. A theory with ``K`` at or below this is as close as the ensemble can tell.
    noise_split : float
        Mean over random splits of ``sup |F_A - F_B| / 2`` for two disjoint halves (each half has the noise of the pool
        times ``sqrt 2``; their distance adds the two in quadrature: ``2 x`` the pool's noise).
    kolmogorov_per_seed : ndarray
        ``K`` of the theory against each seed alone (the realization scatter).
    l1, l1_noise : float
        ``sum |m_theory - m_pool|`` over the bin masses of ``edges`` (first bin from 0
        with the delta peaks, last bin open to infinity) and its bootstrap median noise.
    contact_fraction_theory, contact_fraction_gfmd, contact_fraction_gfmd_sd : float
        One definition for both: ``P(p > threshold)`` with GFMD's ``threshold`` (0 for the hard wall, ``0.01 p0`` for
        exponential walls); the GFMD value is the mean over seeds, ``_sd`` the seed-to-seed standard deviation.
    sd_theory, sd_gfmd, sd_gfmd_sd, skewness_theory, skewness_gfmd, skewness_gfmd_sd : float
        Standard deviation (pressure units) and skewness; GFMD: mean and seed-to-seed sd of the per-seed values.
        ``sd_pool``/``skewness_pool`` are those of the pooled distribution.
    p, cdf_theory, cdf_pool, cdf_lo, cdf_hi : ndarray
        For plots: pressures ``>= p_min`` (at most 2000), the theory's and the pooled
        CDF there, and the pool's 95 % bootstrap band.
    """

    kolmogorov: float
    kolmogorov_ci: tuple
    noise_bootstrap: float
    noise_split: float
    kolmogorov_per_seed: Array
    l1: float
    l1_noise: float
    p_min: float
    edges: Array
    n_seeds: int
    n_excluded: int
    seeds: tuple
    threshold: float
    contact_fraction_theory: float
    contact_fraction_gfmd: float
    contact_fraction_gfmd_sd: float
    sd_theory: float
    sd_gfmd: float
    sd_gfmd_sd: float
    sd_pool: float
    skewness_theory: float
    skewness_gfmd: float
    skewness_gfmd_sd: float
    skewness_pool: float
    p: Array = field(default_factory=lambda: np.zeros(0))
    cdf_theory: Array = field(default_factory=lambda: np.zeros(0))
    cdf_pool: Array = field(default_factory=lambda: np.zeros(0))
    cdf_lo: Array = field(default_factory=lambda: np.zeros(0))
    cdf_hi: Array = field(default_factory=lambda: np.zeros(0))

    def __repr__(self) -> str:  # the report, not the arrays
        return "EnsembleComparison(\n  " + self.summary().replace("\n", "\n  ") + "\n)"

    def summary(self) -> str:
        """Multi-line text report."""
        ps = self.kolmogorov_per_seed
        return "\n".join([
            f"K over p >= {self.p_min:.4g}: {self.kolmogorov:.4f} (95% bootstrap {self.kolmogorov_ci[0]:.4f}-"
            f"{self.kolmogorov_ci[1]:.4f}); ensemble noise {self.noise_bootstrap:.4f} (bootstrap), "
            f"{self.noise_split:.4f} (split halves); {self.n_seeds} seeds ({self.n_excluded} not converged, excluded)",
            f"per-seed K: median {np.median(ps):.4f}, 5-95% {np.percentile(ps, 5):.4f}-{np.percentile(ps, 95):.4f}",
            f"L1 of bin masses: {self.l1:.4f} (noise {self.l1_noise:.4f})",
            f"contact fraction (p > {self.threshold:.3g}): theory {self.contact_fraction_theory:.4f}, "
            f"GFMD {self.contact_fraction_gfmd:.4f} +- {self.contact_fraction_gfmd_sd:.4f} (seed sd)",
            f"sd: theory {self.sd_theory:.4g}, GFMD {self.sd_gfmd:.4g} +- {self.sd_gfmd_sd:.2g} "
            f"(pool {self.sd_pool:.4g})",
            f"skewness: theory {self.skewness_theory:.3f}, GFMD {self.skewness_gfmd:.3f} +- "
            f"{self.skewness_gfmd_sd:.3f} (pool {self.skewness_pool:.3f})",
        ])


def compare_ensemble(theory: Any, records_or_group: Any, *, p_min: Optional[float] = None,
                     edges: Optional[ArrayLike] = None, n_boot: int = 400, n_split: int = 200,
                     seed: int = 0) -> EnsembleComparison:
    """Compare a theory with a pooled GFMD ensemble, with the ensemble's noise beside it.

    Parameters
    ----------
    theory : PressureDistribution or any object with ``cdf(p)``
        ``cdf`` includes the delta peak at ``p = 0``. Moments come from
        ``theory.moment`` when present, else from the CDF.
    records_or_group : group or sequence of records
        One pool: one wall, load and grid (e.g. ``bundled_ensemble("fig1_n1024").group(0.25)`` or the list of its
        ``records``). Non-converged records are excluded and counted.
    p_min : float, optional
        Lower end of the Kolmogorov supremum; default ``p0/20`` (``p0`` the records' mean pressure), below which
        the split between a delta peak and a soft wall's tiny pressures is a convention.
    edges : array, optional
        Bin edges for the L1 of bin masses (default 50 uniform bins on
        ``[0, pooled 99.9 % quantile]``, plus the open bin above).
    n_boot, n_split : int
        Bootstrap resamples of seeds and random half splits.
    seed : int
        Random seed of the resampling.

    Returns
    -------
    EnsembleComparison
        Distances are dimensionless; sd in pressure units.
    """
    recs_all = list(getattr(records_or_group, "records", records_or_group))
    recs_all += list(getattr(records_or_group, "excluded", ()))
    recs = [r for r in recs_all if bool(getattr(r, "converged", True))]
    n_excl = len(recs_all) - len(recs)
    if len(recs) < 2:
        raise ValueError(f"records_or_group must hold at least 2 converged records; got {len(recs)} "
                         f"({n_excl} not converged)")
    p0 = float(recs[0].mean_pressure)
    if any(abs(float(r.mean_pressure) - p0) > 1e-12 * p0 for r in recs):
        raise ValueError("records_or_group mixes mean pressures: compare one pool (one wall, load, grid)")
    zetas = {getattr(r, "zeta", None) for r in recs}
    ns = {getattr(r, "n", None) for r in recs}
    if len(zetas) > 1 or len(ns) > 1:
        raise ValueError(f"records_or_group mixes walls {zetas} or grids {ns}: compare one pool")
    p_min = p0 / 20.0 if p_min is None else float(p_min)
    if not (np.isfinite(p_min) and p_min >= 0):
        raise ValueError(f"p_min must be a finite pressure >= 0; got {p_min!r}")
    S = len(recs)
    x = np.unique(np.concatenate([np.asarray(r.quantiles, float) for r in recs] + [[p_min]]))
    x = x[x >= p_min]
    if x.size > 40000:
        x = x[np.linspace(0, x.size - 1, 40000).astype(int)]
    C = np.array([_record_cdf(r, x) for r in recs])
    T = np.asarray(theory.cdf(x), dtype=float)
    F = C.mean(axis=0)
    K = float(np.max(np.abs(T - F)))
    per_seed = np.max(np.abs(C - T), axis=1)
    rng = np.random.default_rng(seed)
    boot_idx = [rng.integers(0, S, S) for _ in range(n_boot)]
    pools = np.array([C[i].mean(0) for i in boot_idx])
    k_boot = np.max(np.abs(T - pools), axis=1)
    noise_b = float(np.median(np.max(np.abs(pools - F), axis=1)))
    sub = np.unique(np.linspace(0, x.size - 1, min(2000, x.size)).astype(int))
    band = np.percentile(pools[:, sub], [2.5, 97.5], axis=0)
    h = S // 2
    splits = [np.max(np.abs(C[perm[:h]].mean(0) - C[perm[h:2 * h]].mean(0))) / 2.0
              for perm in (rng.permutation(S) for _ in range(n_split))]
    if edges is None:
        top = float(np.mean([np.interp(0.999, r.levels, r.quantiles) for r in recs]))
        edges_arr = np.linspace(0.0, top, 51)
    else:
        edges_arr = np.asarray(edges, dtype=float)
        if edges_arr.ndim != 1 or edges_arr.size < 2 or np.any(np.diff(edges_arr) <= 0) or edges_arr[0] < 0:
            raise ValueError("edges must be increasing pressures >= 0 (at least 2)")
    Ce = np.array([_record_cdf(r, edges_arr) for r in recs])
    Ce[:, 0] = 0.0  # first bin starts at 0 and holds the delta peak
    Me = np.concatenate([np.diff(Ce, axis=1), 1.0 - Ce[:, -1:]], axis=1)
    Te = np.asarray(theory.cdf(edges_arr), dtype=float)
    Te[0] = 0.0
    Mt = np.concatenate([np.diff(Te), [1.0 - Te[-1]]])
    Mp = Me.mean(0)
    l1 = float(np.sum(np.abs(Mt - Mp)))
    l1_noise = float(np.median([np.sum(np.abs(Me[i].mean(0) - Mp)) for i in boot_idx]))
    thr = float(getattr(recs[0], "contact_threshold", 0.0))
    cf_t = float(theory.contact_area(thr) if hasattr(theory, "contact_area") else 1.0 - theory.cdf(thr))
    cf = np.array([float(r.contact_fraction) for r in recs])
    mean_s, var_s, th_s = (np.array([float(getattr(r, key)) for r in recs])
                           for key in ("mean", "variance", "third_central"))
    sd_s = np.sqrt(var_s)
    sk_s = np.divide(th_s, sd_s**3, out=np.zeros_like(th_s), where=sd_s > 0)  # (a seed or block out of contact: 0)
    m = mean_s.mean()
    var_p = float(np.mean(var_s + (mean_s - m) ** 2))
    th_p = float(np.mean(th_s + 3 * var_s * (mean_s - m) + (mean_s - m) ** 3))
    tm, tv, tt = _theory_moments(theory, float(np.max([r.quantiles[-1] for r in recs])))
    sd_t = float(np.sqrt(max(tv, 0.0)))
    return EnsembleComparison(
        kolmogorov=K, kolmogorov_ci=(float(np.percentile(k_boot, 2.5)), float(np.percentile(k_boot, 97.5))),
        noise_bootstrap=noise_b, noise_split=float(np.mean(splits)), kolmogorov_per_seed=per_seed,
        l1=l1, l1_noise=l1_noise, p_min=p_min, edges=edges_arr, n_seeds=S, n_excluded=n_excl,
        seeds=tuple(int(getattr(r, "seed", -1)) for r in recs), threshold=thr,
        contact_fraction_theory=cf_t, contact_fraction_gfmd=float(cf.mean()),
        contact_fraction_gfmd_sd=float(cf.std(ddof=1)),
        sd_theory=sd_t, sd_gfmd=float(sd_s.mean()), sd_gfmd_sd=float(sd_s.std(ddof=1)), sd_pool=float(np.sqrt(var_p)),
        skewness_theory=float(tt / sd_t**3) if sd_t > 0 else 0.0, skewness_gfmd=float(sk_s.mean()),
        skewness_gfmd_sd=float(sk_s.std(ddof=1)), skewness_pool=float(th_p / var_p**1.5) if var_p > 0 else 0.0,
        p=x[sub], cdf_theory=T[sub], cdf_pool=F[sub], cdf_lo=band[0], cdf_hi=band[1],
    )
