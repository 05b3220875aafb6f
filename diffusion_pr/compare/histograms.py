"""A simulated pressure field as a histogram (:class:`SimulatedHistogram`) and a theory's bin averages.

Pressures in any unit shared by theory and simulation; densities in 1/pressure.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SimulatedHistogram:
    """A pressure histogram of one simulated contact.

    Attributes
    ----------
    edges : ndarray
        Bin edges (units of pressure), increasing, ``edges[0] >= 0``.
    density : ndarray
        Density of the continuous part in each bin (1 / pressure), normalized
        so that ``sum(density * widths) + zero_weight == 1``.
    zero_weight : float
        Fraction of the area with exactly zero pressure (hard wall).
    moments : dict
        ``mean``, ``variance``, ``third_central`` (pressure, pressure^2,
        pressure^3) of the whole field, computed from the field.
    quantile_levels, quantiles : ndarray, optional
        The empirical quantile function of the field (for a Kolmogorov distance
        at full resolution).
    metadata : dict
        Provenance (parameters, seed, solver tolerance, residual, ...).
    """

    edges: Array
    density: Array
    zero_weight: float = 0.0
    moments: dict = field(default_factory=dict)
    quantile_levels: Optional[Array] = None
    quantiles: Optional[Array] = None
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        edges = np.asarray(self.edges, dtype=float)
        density = np.asarray(self.density, dtype=float)
        if edges.ndim != 1 or density.shape != (edges.size - 1,) or edges.size < 2:
            raise ValueError(f"edges must have one more entry than density; got {edges.shape} and {density.shape}")
        if np.any(np.diff(edges) <= 0) or not np.all(np.isfinite(edges)):
            raise ValueError("edges must be finite and strictly increasing")
        if np.any(density < 0) or not np.all(np.isfinite(density)):
            raise ValueError("density must be finite and >= 0")
        object.__setattr__(self, "edges", edges)
        object.__setattr__(self, "density", density)

    @property
    def centers(self) -> Array:
        """Bin centres (units of pressure)."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    @property
    def widths(self) -> Array:
        """Bin widths (units of pressure)."""
        return np.diff(self.edges)

    @property
    def contact_fraction(self) -> float:
        """``1 - zero_weight`` (meaningful for the hard wall)."""
        return 1.0 - float(self.zero_weight)

    def fraction_above(self, threshold: float = 0.0) -> float:
        """Fraction of the field with pressure ``> threshold`` (units of pressure).

        Exact for ``threshold = 0`` (``1 - zero_weight``) and for the
        threshold given to :meth:`from_pressures` (counted on the field);
        otherwise interpolated in the stored quantile function (resolution
        one quantile level, ``1/(len(quantile_levels) - 1)``).
        """
        threshold = float(threshold)
        if not np.isfinite(threshold) or threshold < 0:
            raise ValueError(f"threshold must be a finite number >= 0; got threshold={threshold!r}")
        if threshold == 0.0:
            return 1.0 - float(self.zero_weight)
        if self.moments.get("contact_threshold") == threshold and "contact_fraction" in self.moments:
            return float(self.moments["contact_fraction"])
        if self.quantiles is None or self.quantile_levels is None:
            raise ValueError("this histogram has no stored quantiles; give contact_threshold to from_pressures")
        below = np.searchsorted(self.quantiles, threshold, side="right")
        return float(1.0 - self.quantile_levels[max(int(below) - 1, 0)]) if below > 0 else 1.0

    @classmethod
    def from_pressures(cls, pressure: ArrayLike, *, bins: int | Sequence[float] = 200,
                       p_max: Optional[float] = None, n_quantiles: int = 2049,
                       contact_threshold: Optional[float] = None,
                       metadata: Optional[dict] = None) -> "SimulatedHistogram":
        """Histogram a pressure field.

        Parameters
        ----------
        pressure : array
            Local pressures (units of pressure), any shape, all ``>= 0``.
        bins : int or sequence
            Number of uniform bins on ``(0, p_max]`` or explicit edges.
        p_max : float, optional
            Upper end of the uniform bins (default: the largest pressure).
        n_quantiles : int
            Number of stored quantile levels of the field (>= 2).
        contact_threshold : float, optional
            Also count the fraction of the field with ``p > contact_threshold``
            (stored in ``moments``; see :meth:`fraction_above`).
        """
        if isinstance(bins, (bool, np.bool_)) or (np.ndim(bins) == 0 and not isinstance(bins, (int, np.integer))):
            raise ValueError(f"bins must be an integer >= 1 or a sequence of edges; got bins={bins!r}")
        if np.ndim(bins) == 0 and int(bins) < 1:
            raise ValueError(f"bins must be an integer >= 1 or a sequence of edges; got bins={bins!r}")
        if isinstance(n_quantiles, (bool, np.bool_)) or not isinstance(n_quantiles, (int, np.integer)) \
                or n_quantiles < 2:
            raise ValueError(f"n_quantiles must be an integer >= 2; got n_quantiles={n_quantiles!r}")
        if p_max is not None and (isinstance(p_max, (str, bytes, bool)) or not np.isfinite(p_max) or p_max <= 0):
            raise ValueError(f"p_max must be a finite number > 0; got p_max={p_max!r}")
        values = np.asarray(pressure, dtype=float).ravel()
        if values.size == 0 or not np.all(np.isfinite(values)):
            raise ValueError("pressure must be a non-empty array of finite values")
        if np.any(values < 0):
            raise ValueError(f"pressure must be >= 0; found min {values.min()!r}")
        n = values.size
        zero = values == 0.0
        zero_weight = float(np.count_nonzero(zero)) / n
        positive = values[~zero]
        if np.ndim(bins) == 0:
            top = float(p_max) if p_max is not None else float(positive.max() if positive.size else 1.0)
            edges = np.linspace(0.0, top, int(bins) + 1)
        else:
            edges = np.asarray(bins, dtype=float)
            if edges.ndim != 1 or edges.size < 2 or not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0) \
                    or edges[0] < 0:
                raise ValueError("bins given as edges must be finite, >= 0 and strictly increasing, at least two; "
                                 f"got bins={bins!r}")
        counts, _ = np.histogram(positive, bins=edges)
        density = counts / (n * np.diff(edges))
        mean = float(values.mean())
        centred = values - mean
        moments = {
            "mean": mean,
            "variance": float(np.mean(centred**2)),
            "third_central": float(np.mean(centred**3)),
            "outside_bins": float(positive.size - counts.sum()) / n,
        }
        if contact_threshold is not None:
            threshold = float(contact_threshold)
            if not np.isfinite(threshold) or threshold < 0:
                raise ValueError(f"contact_threshold must be a finite number >= 0; got {contact_threshold!r}")
            moments["contact_threshold"] = threshold
            moments["contact_fraction"] = float(np.count_nonzero(values > threshold)) / n
        levels = np.linspace(0.0, 1.0, n_quantiles)
        quantiles = np.quantile(values, levels)
        return cls(edges, density, zero_weight, moments, levels, quantiles, dict(metadata or {}))

    def rebinned(self, factor: int) -> "SimulatedHistogram":
        """Merge ``factor`` adjacent bins (fewer, less noisy bins)."""
        factor = int(factor)
        if factor < 1:
            raise ValueError(f"factor must be an integer >= 1; got factor={factor!r}")
        n = (self.density.size // factor) * factor
        mass = (self.density * self.widths)[:n].reshape(-1, factor).sum(axis=1)
        edges = self.edges[: n + 1 : factor]
        return SimulatedHistogram(edges, mass / np.diff(edges), self.zero_weight, dict(self.moments),
                                  self.quantile_levels, self.quantiles, dict(self.metadata))


def bin_averaged_density(theory: Any, edges: ArrayLike) -> Array:
    """Average of a theory's continuous density over each bin (1 / pressure).

    Uses the theory's cumulative distribution, so narrow features are
    integrated exactly rather than sampled at bin centres; the ``delta(p)``
    peak is excluded.
    """
    edges = np.asarray(edges, dtype=float)
    cdf = np.asarray(theory.cdf(edges), dtype=float)
    # theory.cdf includes zero_weight for p >= 0; differences cancel it except
    # across p = 0 itself, which no bin here straddles (edges[0] >= 0).
    return np.diff(cdf) / np.diff(edges)
