"""Pressure histograms with the hard-wall non-contact delta peak kept apart: the bins, the
weight of exactly-zero pressures, the moments, the contact fraction at the solver's
threshold, the field's quantile function and provenance (what a comparison with a theory
needs)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ._validation import check_int, check_positive, check_real
from .solvers import ContactResult

__all__ = ["pressure_histogram", "PressureHistogram"]


@dataclass(frozen=True, eq=False)
class PressureHistogram:
    """The pressure distribution of one contact.

    Attributes
    ----------
    edges : ndarray
        Bin edges [pressure], finite and strictly increasing.
    density : ndarray
        Density of the continuous part (pressures != 0) per bin [1/pressure], normalised
        so that ``sum(density * widths) + zero_weight + (values outside the bins) == 1``.
    zero_weight : float
        Fraction of exactly-zero pressures (the hard-wall non-contact peak).
    moments : dict
        ``mean``, ``variance``, ``third_central`` of the whole field, ``outside_bins``
        (fraction of non-zero values outside the bins) and, when known,
        ``contact_threshold`` [pressure] with ``contact_fraction`` counted on the field.
    quantile_levels, quantiles : ndarray, optional
        The field's empirical quantile function (``numpy.quantile``, linear).
    metadata : dict
        Provenance (solver, wall, parameters, ...).
    counts : ndarray, optional
        Raw counts of the non-zero pressures per bin; ``n_total`` values in the field,
        ``n_outside`` non-zero ones outside the bins.
    """

    edges: np.ndarray
    density: np.ndarray
    zero_weight: float = 0.0
    moments: dict = field(default_factory=dict)
    quantile_levels: Optional[np.ndarray] = None
    quantiles: Optional[np.ndarray] = None
    metadata: dict = field(default_factory=dict)
    counts: Optional[np.ndarray] = None
    n_total: int = 0
    n_outside: int = 0

    def __post_init__(self) -> None:
        edges = np.asarray(self.edges, dtype=float)
        density = np.asarray(self.density, dtype=float)
        if edges.ndim != 1 or edges.size < 2 or density.shape != (edges.size - 1,):
            raise ValueError(f"edges must have one more entry than density; got {edges.shape} and {density.shape}")
        if not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0):
            raise ValueError("edges must be finite and strictly increasing")
        if not np.all(np.isfinite(density)) or np.any(density < 0):
            raise ValueError("density must be finite and >= 0")
        object.__setattr__(self, "edges", edges)
        object.__setattr__(self, "density", density)

    #: Bin centres and widths [pressure].
    centers = property(lambda self: 0.5 * (self.edges[1:] + self.edges[:-1]))
    widths = property(lambda self: np.diff(self.edges))

    @property
    def contact_threshold(self) -> float:
        """The default threshold of :meth:`contact_area` [pressure]: the solver's (hard
        wall 0, exponential wall ``EXP_CONTACT_THRESHOLD * p0``) when known, else 0."""
        return float(self.moments.get("contact_threshold", 0.0))

    def contact_area(self, threshold: float | None = None) -> float:
        """Fraction of the field with pressure ``> threshold`` [pressure] (default
        :attr:`contact_threshold`); see :meth:`fraction_above`."""
        return self.fraction_above(self.contact_threshold if threshold is None else threshold)

    contact_fraction = property(contact_area, doc=":meth:`contact_area` at its default threshold.")

    def fraction_above(self, threshold: float = 0.0) -> float:
        """Fraction of the field with pressure ``> threshold`` [pressure, >= 0].

        Exact for ``threshold = 0`` (``1 - zero_weight``) and for the stored
        ``contact_threshold`` (counted on the field); otherwise read from the quantile
        function (resolution one quantile level, ``1/(len(quantile_levels) - 1)``).
        """
        threshold = check_real("threshold", threshold, low=0.0)
        if threshold == 0.0:
            return 1.0 - float(self.zero_weight)
        if self.moments.get("contact_threshold") == threshold and "contact_fraction" in self.moments:
            return float(self.moments["contact_fraction"])
        if self.quantiles is None or self.quantile_levels is None:
            raise ValueError("this histogram has no stored quantiles; give contact_threshold to from_pressures")
        below = np.searchsorted(self.quantiles, threshold, side="right")
        return float(1.0 - self.quantile_levels[max(int(below) - 1, 0)]) if below > 0 else 1.0

    @classmethod
    def from_pressures(cls, pressure, *, bins=200, p_max: float | None = None, n_quantiles: int = 2049,
                       contact_threshold: float | None = None, metadata: dict | None = None) -> "PressureHistogram":
        """Histogram a pressure field.

        Parameters
        ----------
        pressure : array
            Local pressures [pressure], any shape, finite and ``>= 0``.
        bins : int or sequence
            Number of uniform bins on ``(0, p_max]`` or explicit edges (``>= 0``).
        p_max : float, optional
            Upper end of the uniform bins (default: the largest pressure).
        n_quantiles : int
            Number of stored quantile levels (>= 2).
        contact_threshold : float, optional
            Count the fraction with ``p > contact_threshold`` (the default of
            :meth:`contact_area`; stored in ``moments``).
        metadata : dict, optional
            Provenance kept with the histogram.
        """
        n_quantiles = check_int("n_quantiles", n_quantiles, minimum=2)
        p_max = None if p_max is None else check_positive("p_max", p_max)
        values = np.asarray(pressure, dtype=float).ravel()
        if values.size == 0 or not np.all(np.isfinite(values)):
            raise ValueError("pressure must be a non-empty array of finite values")
        if np.any(values < 0):
            raise ValueError(f"pressure must be >= 0; found min {values.min()!r}")
        n = values.size
        positive = values[values != 0.0]
        if np.ndim(bins) == 0:
            top = p_max if p_max is not None else float(positive.max() if positive.size else 1.0)
            edges = np.linspace(0.0, top, check_int("bins", bins, minimum=1) + 1)
        else:
            edges = np.asarray(bins, dtype=float)
            if edges.ndim != 1 or edges.size < 2 or not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0) \
                    or edges[0] < 0:
                raise ValueError("bins given as edges must be finite, >= 0 and strictly increasing, at least two; "
                                 f"got bins={bins!r}")
        counts, _ = np.histogram(positive, bins=edges)
        centred = values - values.mean()
        moments = dict(mean=float(values.mean()), variance=float(np.mean(centred**2)),
                       third_central=float(np.mean(centred**3)),
                       outside_bins=float(positive.size - counts.sum()) / n)
        if contact_threshold is not None:
            moments["contact_threshold"] = check_real("contact_threshold", contact_threshold, low=0.0)
            moments["contact_fraction"] = float(np.count_nonzero(values > moments["contact_threshold"])) / n
        levels = np.linspace(0.0, 1.0, n_quantiles)
        return cls(edges, counts / (n * np.diff(edges)), float(n - positive.size) / n, moments, levels,
                   np.quantile(values, levels), dict(metadata or {}), counts, n, int(positive.size - counts.sum()))

    def rebinned(self, factor: int) -> "PressureHistogram":
        """Merge ``factor`` adjacent bins (a trailing remainder of bins is dropped)."""
        factor = check_int("factor", factor, minimum=1)
        n = (self.density.size // factor) * factor
        mass = (self.density * self.widths)[:n].reshape(-1, factor).sum(axis=1)
        edges = self.edges[: n + 1: factor]
        counts = None if self.counts is None else self.counts[:n].reshape(-1, factor).sum(axis=1)
        return PressureHistogram(edges, mass / np.diff(edges), self.zero_weight, dict(self.moments),
                                 self.quantile_levels, self.quantiles, dict(self.metadata), counts, self.n_total,
                                 self.n_outside)


def pressure_histogram(result, bins=100, range=None, n_quantiles: int = 2049) -> PressureHistogram:
    """Histogram of the local pressures of a solver result.

    Parameters
    ----------
    result : ContactResult
        A :func:`~gfmd_ref.solve_contact` result: its ``pressure``, its
        ``contact_threshold`` (the default of :meth:`PressureHistogram.contact_area`)
        and its parameters (``metadata``). For a bare pressure array use
        :meth:`PressureHistogram.from_pressures` and give the threshold.
    bins : int or sequence
        Number of bins or bin edges (as :func:`numpy.histogram`).
    range : (float, float), optional
        Histogram range of the non-zero pressures (default: their min and max).
    n_quantiles : int
        Number of stored quantile levels (>= 2).
    """
    if not isinstance(result, ContactResult):
        raise TypeError("pressure_histogram needs a gfmd_ref.ContactResult (from solve_contact); got "
                        f"{type(result).__name__}: for a bare pressure array use "
                        "PressureHistogram.from_pressures(pressure, bins=..., contact_threshold=...)")
    nz = result.pressure[result.pressure != 0.0]
    if np.ndim(bins) == 0:
        bins = check_int("bins", bins, minimum=1)
        if range is None:
            lo, hi = (float(nz.min()), float(nz.max())) if nz.size else (0.0, 1.0)
            range = (lo, hi if hi > lo else lo + max(abs(lo), 1.0) * 1e-12)
        bins = np.histogram_bin_edges(nz, bins=bins, range=range)
    inter = result.interaction
    meta = dict(interaction=type(inter).__name__, zeta=getattr(inter, "zeta", None),
                mean_pressure=result.mean_pressure, E_star=result.E_star, length=result.length, tol=result.tol,
                method=result.method, converged=result.converged, residual=result.residual,
                iterations=result.iterations)
    return PressureHistogram.from_pressures(result.pressure, bins=bins, n_quantiles=n_quantiles,
                                            contact_threshold=result.contact_threshold, metadata=meta)
