"""Pressure histograms with the hard-wall non-contact delta peak kept apart."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["pressure_histogram", "PressureHistogram"]


@dataclass(frozen=True, eq=False)
class PressureHistogram:
    """``density`` is the density of the continuous part (pressures != 0), normalised so
    that ``sum(density * widths) + zero_weight == 1``; ``zero_weight`` is the fraction
    of exactly-zero pressures (the hard-wall non-contact peak); ``counts`` are the raw
    counts of the non-zero pressures per bin; ``n_outside`` non-zero values fell
    outside ``range`` (they count in the normalisation, not in any bin)."""

    edges: np.ndarray
    centers: np.ndarray
    density: np.ndarray
    zero_weight: float
    counts: np.ndarray
    n_total: int
    n_outside: int

    @property
    def widths(self) -> np.ndarray:
        return np.diff(self.edges)


def pressure_histogram(result_or_pressure, bins=100, range=None) -> PressureHistogram:
    """Histogram of local pressures.

    Parameters
    ----------
    result_or_pressure : ContactResult or array
        A solver result (its ``pressure`` is used) or any array of pressures.
    bins : int or sequence
        Number of bins or bin edges (as :func:`numpy.histogram`).
    range : (float, float), optional
        Histogram range of the non-zero pressures (default: their min and max).
    """
    p = getattr(result_or_pressure, "pressure", result_or_pressure)
    p = np.asarray(p, dtype=np.float64).ravel()
    if p.size == 0:
        raise ValueError("pressure must be a non-empty array; got size 0")
    if not np.all(np.isfinite(p)):
        raise ValueError("pressure must be finite; got NaN/inf values")
    ntot = p.size
    nz = p[p != 0.0]
    zero_weight = (ntot - nz.size) / ntot
    if range is None:
        if nz.size:
            lo, hi = float(nz.min()), float(nz.max())
            if hi <= lo:
                hi = lo + max(abs(lo), 1.0) * 1e-12
        else:
            lo, hi = 0.0, 1.0
        range = (lo, hi)
    counts, edges = np.histogram(nz, bins=bins, range=range)
    inside = int(counts.sum())
    widths = np.diff(edges)
    density = counts / (ntot * widths)
    centers = 0.5 * (edges[1:] + edges[:-1])
    return PressureHistogram(
        edges=edges,
        centers=centers,
        density=density,
        zero_weight=float(zero_weight),
        counts=counts,
        n_total=int(ntot),
        n_outside=int(nz.size - inside),
    )
