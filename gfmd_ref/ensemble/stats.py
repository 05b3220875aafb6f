"""Reductions of an ensemble with error bars, from the converged records of one pool (an
:class:`~gfmd_ref.ensemble.store.EnsembleGroup` or a list of records). The pooled distribution
gives every seed the same area, ``F(p) = mean_s F_s(p)``, each ``F_s`` linear between its
stored quantiles, so distances between such CDFs are exact on the union of the knots
(:func:`cdf_grid`). Kolmogorov distances are taken over ``p >= p_min``, default ``p0/20``
(below it the hard-wall peak and the soft walls' tiny pressures would be compared).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from .store import parse_wall

__all__ = ["group_records", "cdf_grid", "cdf_matrix", "pooled_cdf", "bootstrap_cdf_band", "bootstrap_density_band",
           "kolmogorov", "NoiseFloor", "noise_floor", "scatter", "finite_size_table"]


def group_records(group_or_records) -> list:
    """Converged records of a group or list (non-converged ones are dropped)."""
    recs = [r for r in getattr(group_or_records, "records", group_or_records) if getattr(r, "converged", True)]
    if not recs:
        raise ValueError("no converged record to reduce")
    return recs


def _default_p_min(recs) -> float:
    return float(recs[0].mean_pressure) / 20.0


def cdf_grid(recs, p_min: Optional[float] = None, max_points: int = 40000) -> np.ndarray:
    """Sorted union of the records' quantile knots ``>= p_min`` (and ``p_min``).

    Above ``max_points`` knots an evenly thinned subset is used (the supremum is then
    exact to about one level step)."""
    recs = group_records(recs)
    p_min = _default_p_min(recs) if p_min is None else float(p_min)
    x = np.unique(np.concatenate([r.quantiles for r in recs] + [[p_min]]))
    x = x[x >= p_min]
    if x.size > max_points:
        x = x[np.linspace(0, x.size - 1, max_points).astype(int)]
    return x


def cdf_matrix(recs, x) -> np.ndarray:
    """``C[s, j] = F_s(x_j)`` for every record ``s``."""
    return np.array([r.cdf(x) for r in group_records(recs)])


def pooled_cdf(recs, p) -> np.ndarray:
    """Pooled CDF (equal area per seed) at pressures ``p``."""
    return cdf_matrix(recs, np.asarray(p, dtype=float)).mean(axis=0)


def _bootstrap(M, n_boot: int, level: float, seed: int):
    """Mean over the rows (seeds) of ``M`` and the ``(1 -+ level)/2`` percentiles of the
    means of ``n_boot`` resamples of the rows (with replacement)."""
    rng = np.random.default_rng(seed)
    S = M.shape[0]
    boot = np.array([M[rng.integers(0, S, S)].mean(axis=0) for _ in range(n_boot)])
    a = 100 * (1 - level) / 2
    return M.mean(axis=0), np.percentile(boot, a, axis=0), np.percentile(boot, 100 - a, axis=0)


def bootstrap_cdf_band(recs, p, *, n_boot: int = 400, level: float = 0.95, seed: int = 0):
    """Pooled CDF at ``p`` and its bootstrap band over seeds (resampled with replacement).

    Returns ``(F, lo, hi)``: the pooled CDF and the ``(1 - level)/2``,
    ``(1 + level)/2`` percentiles of the resampled pooled CDF at each ``p``."""
    return _bootstrap(cdf_matrix(recs, np.asarray(p, dtype=float)), n_boot, level, seed)


def bootstrap_density_band(recs, edges, *, n_boot: int = 400, level: float = 0.95, seed: int = 0):
    """Pooled density of the bins ``edges`` (mass / width, the delta peak at 0 is
    not in it) and its bootstrap band. Returns ``(density, lo, hi)``."""
    edges = np.asarray(edges, dtype=float)
    return _bootstrap(np.diff(cdf_matrix(recs, edges), axis=1) / np.diff(edges), n_boot, level, seed)


def kolmogorov(first, second, p_min: Optional[float] = None) -> float:
    """``sup |F_1 - F_2|`` over ``p >= p_min`` between two pools (lists or groups)."""
    a, b = group_records(first), group_records(second)
    x = cdf_grid(a + b, p_min if p_min is not None else _default_p_min(a))
    return float(np.max(np.abs(pooled_cdf(a, x) - pooled_cdf(b, x))))


@dataclass(frozen=True)
class NoiseFloor:
    """Sampling noise of an N-seed pooled distribution, from disjoint random halves.

    ``sizes`` N; ``k_pair[i]`` the mean Kolmogorov distance between two disjoint
    random N-seed pools (over ``repeats`` draws), ``k_noise = k_pair/sqrt(2)`` the
    expected distance of one N-seed pool from the infinite-ensemble distribution
    (independent pools: the two errors add in quadrature); ``coefficient`` the
    median of ``k_noise sqrt(N)`` (noise ~ coefficient/sqrt(N));
    ``k_noise_full`` that law at the full ensemble size ``n_seeds``.
    """

    sizes: np.ndarray
    k_pair: np.ndarray
    k_pair_sd: np.ndarray
    k_noise: np.ndarray
    coefficient: float
    n_seeds: int
    k_noise_full: float
    p_min: float


def noise_floor(recs, *, sizes: Optional[Sequence[int]] = None, repeats: int = 200, p_min: Optional[float] = None,
                seed: int = 0) -> NoiseFloor:
    """K(N) of the ensemble itself (see :class:`NoiseFloor`)."""
    recs = group_records(recs)
    S = len(recs)
    if S < 2:
        raise ValueError(f"noise_floor needs at least 2 converged seeds; got {S}")
    p_min = _default_p_min(recs) if p_min is None else float(p_min)
    if sizes is None:
        sizes = [k for k in (1, 2, 4, 8, 16, 32, 64) if 2 * k <= S]
    sizes = np.array([int(k) for k in sizes])
    if np.any(sizes < 1) or np.any(2 * sizes > S):
        raise ValueError(f"sizes must be in [1, {S // 2}] (two disjoint pools of N seeds); got {sizes.tolist()}")
    C = cdf_matrix(recs, cdf_grid(recs, p_min))
    rng = np.random.default_rng(seed)
    ks = np.array([[np.max(np.abs(C[perm[:k]].mean(0) - C[perm[k:2 * k]].mean(0)))
                    for perm in (rng.permutation(S) for _ in range(repeats))] for k in sizes])
    k_noise = ks.mean(axis=1) / np.sqrt(2.0)
    coef = float(np.median(k_noise * np.sqrt(sizes)))
    return NoiseFloor(sizes, ks.mean(axis=1), ks.std(axis=1), k_noise, coef, S, coef / np.sqrt(S), p_min)


def scatter(recs, attr: str) -> tuple:
    """``(mean, sd, sem)`` of a per-record scalar (``contact_fraction``, ``sd``, ``skewness``, ...)."""
    v = np.array([getattr(r, attr) for r in group_records(recs)], dtype=float)
    sd = float(v.std(ddof=1)) if v.size > 1 else 0.0
    return float(v.mean()), sd, sd / np.sqrt(v.size)


def finite_size_table(ensemble, wall, *, n_ref: int = 1024, mean_pressure=None, p_min: Optional[float] = None) -> list:
    """The same physical system at several grids (same surface family, ``L = n``).

    ``wall`` is ``"hard"`` or a zeta in grid units *of the grid* ``n_ref``: all
    lengths scale with ``L = n``, so the same physical wall has ``zeta n / n_ref``
    grid units on an ``n x n`` grid (records with that zeta are used). One row per
    grid size present: seeds, contact fraction, sd/p0 and skewness (mean +- sem over
    seeds), and K between this grid's pooled CDF and the finest grid's, beside the
    noise of those two pools (the quadrature sum of their split-half noise
    estimates; 0 when a pool has fewer than 2 seeds).
    """
    z_ref = parse_wall(wall)
    recs = [r for r in ensemble.records if r.converged
            and (mean_pressure is None or np.isclose(r.mean_pressure, mean_pressure, rtol=1e-12))
            and ((r.zeta is None and z_ref is None)
                 or (None not in (r.zeta, z_ref) and np.isclose(r.zeta, z_ref * r.n / n_ref, rtol=1e-9)))]
    ns = sorted({r.n for r in recs})
    if not ns:
        raise ValueError(f"no converged records for wall={wall!r} (zeta scaled as n/{n_ref})")
    pools = {n: [r for r in recs if r.n == n] for n in ns}
    finest = pools[ns[-1]]

    def noise(pool):
        if len(pool) < 2:
            return 0.0
        nf = noise_floor(pool, sizes=[len(pool) // 2], repeats=50, p_min=p_min)
        return float(nf.k_noise[0] * np.sqrt(nf.sizes[0] / len(pool)))

    nf_fine = noise(finest)
    rows = []
    for n in ns:
        pool = pools[n]
        p0 = pool[0].mean_pressure
        cf = scatter(pool, "contact_fraction")
        sd = scatter(pool, "sd")
        sk = scatter(pool, "skewness")
        k = kolmogorov(pool, finest, p_min) if n != ns[-1] else 0.0
        rows.append(dict(n=n, seeds=len(pool), contact_fraction=cf[0], contact_fraction_sem=cf[2],
                         sd_over_p0=sd[0] / p0, sd_over_p0_sem=sd[2] / p0, skewness=sk[0], skewness_sem=sk[2],
                         k_to_finest=k, k_noise=float(np.hypot(noise(pool), nf_fine)) if n != ns[-1] else 0.0))
    return rows
