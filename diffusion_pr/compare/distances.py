"""Distances between a theory and a simulated histogram (:data:`SimulatedHistogram`): :func:`compare` (L1 of bin
masses, Kolmogorov, moments, contact fractions) from a theory's bin averages (:func:`bin_averaged_density`), and the one
Kolmogorov distance from a field's quantile function (:func:`kolmogorov_distance`, also between two fields:
:func:`kolmogorov_between`).

Distances dimensionless; pressures in any unit shared by both sides, densities in 1/pressure."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np
from gfmd_ref.histogram import PressureHistogram
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: the one histogram type of a simulated pressure field, shared with the GFMD reference (which never imports
#: diffusion_pr): :class:`gfmd_ref.PressureHistogram`
SimulatedHistogram = PressureHistogram


def bin_averaged_density(theory: Any, edges: ArrayLike) -> Array:
    """Average of a theory's continuous density over each bin (1 / pressure). Uses the theory's cumulative distribution,
    so narrow features are integrated exactly rather than sampled at bin centres; the ``delta(p)`` peak is excluded."""
    edges = np.asarray(edges, dtype=float)
    cdf = np.asarray(theory.cdf(edges), dtype=float)
    # (theory.cdf includes zero_weight for p >= 0: differences cancel it, no bin straddling p = 0 as edges[0] >= 0)
    return np.diff(cdf) / np.diff(edges)


@dataclass(frozen=True)
class Comparison:
    """Distances and moments between a theory and a simulated histogram.

    Attributes
    ----------
    l1 : float
        ``sum |m_theory - m_sim|`` over the bin masses, the ``delta(p)`` peaks in the first bin (0 ... 2,
        dimensionless); see :func:`compare`.
    kolmogorov : float
        ``sup |F_theory - F_sim|`` over ``p >= edges[1]`` (dimensionless).
    moments_theory, moments_sim : dict
        ``mean``, ``variance``, ``third_central`` of both (pressure^k).
    contact_fraction_theory, contact_fraction_sim : float
        Fraction of the area with ``p > contact_threshold``: the theory's ``contact_area(threshold)`` and
        :meth:`SimulatedHistogram.fraction_above`.
    contact_threshold : float
        The threshold (units of pressure).
    """

    l1: float
    kolmogorov: float
    moments_theory: dict
    moments_sim: dict
    contact_fraction_theory: float
    contact_fraction_sim: float
    contact_threshold: float = 0.0


def _as_histogram(simulated: Any, theory: Any) -> SimulatedHistogram:
    """``simulated`` as a histogram: a histogram as it is, a GFMD ``ContactResult`` by
    :func:`gfmd_ref.pressure_histogram`, a pressure field (any shape) counted at the theory's ``contact_threshold``."""
    if isinstance(simulated, PressureHistogram):
        return simulated
    if hasattr(simulated, "pressure") and hasattr(simulated, "contact_threshold"):
        from gfmd_ref import pressure_histogram

        return pressure_histogram(simulated)
    field = np.asarray(simulated)
    if field.dtype.kind not in "iuf" or field.size < 2:
        raise TypeError("compare takes a PressureHistogram, a gfmd_ref ContactResult, a pressure field (a real array) "
                        f"or an ensemble (group or records); got {type(simulated).__name__}")
    return PressureHistogram.from_pressures(field, contact_threshold=getattr(theory, "contact_threshold", 0.0))


def compare(theory: Any, simulated: Any, *, contact_threshold: Optional[float] = None) -> Any:
    """Compare a :class:`~diffusion_pr.result.PressureDistribution` with a simulation.

    ``simulated``: a :data:`SimulatedHistogram`, a GFMD ``ContactResult``, a pressure field (an array of local
    pressures), or an ensemble (an ``EnsembleGroup`` or a sequence of records: then this is
    :func:`~diffusion_pr.compare.compare_ensemble`, with the ensemble's noise).

    Both distances are taken at the histogram's resolution: the ``delta(p)`` peaks (the theory's ``zero_weight`` and the
    simulation's exactly-zero pressures) are counted in the first bin ``[0, edges[1])``, since below one bin width a
    soft wall's tiny pressures cannot be told from ``p = 0``.  The contact fractions are reported separately.

    * ``l1 = sum_i |m_theory,i - m_sim,i|`` over bin masses, plus the theory's mass beyond the last edge and the
      simulation's pressures outside the bins.
    * ``kolmogorov = sup |F_theory(p) - F_sim(p)|`` over ``p >= edges[1]``, from the stored quantile function when
      available (both sides of every empirical jump), else at the bin edges.
    * contact fractions: the fraction with ``p > contact_threshold`` on both sides; default the theory's
      ``contact_threshold`` (0 on a hard wall, GFMD's ``0.01 p0`` on an exponential wall), else the histogram's."""
    if hasattr(simulated, "records") or (isinstance(simulated, (list, tuple)) and simulated
                                         and hasattr(simulated[0], "quantiles")):
        from .ensemble import compare_ensemble

        return compare_ensemble(theory, simulated)
    hist = _as_histogram(simulated, theory)
    if contact_threshold is None:
        contact_threshold = getattr(theory, "contact_threshold", None)
    threshold = float(hist.contact_threshold if contact_threshold is None else contact_threshold)
    if not np.isfinite(threshold) or threshold < 0:
        raise ValueError(f"contact_threshold must be a finite number >= 0; got {contact_threshold!r}")
    m_theory, m_sim = bin_averaged_density(theory, hist.edges) * hist.widths, hist.density * hist.widths
    m_theory[0] += float(theory.zero_weight)
    m_sim[0] += float(hist.zero_weight)
    beyond = max(0.0, 1.0 - float(theory.cdf(hist.edges[-1])))
    l1 = float(np.sum(np.abs(m_theory - m_sim))) + beyond + float(hist.moments.get("outside_bins", 0.0))
    p_floor = float(hist.edges[1])
    if hist.quantiles is not None and hist.quantile_levels is not None:
        ks = kolmogorov_distance(theory.cdf, hist.quantiles, hist.quantile_levels, p_floor=p_floor,
                                 zero_weight=float(theory.zero_weight))
    else:
        ks = float(np.max(np.abs(np.asarray(theory.cdf(hist.edges[1:])) - np.cumsum(m_sim))))
    moments_theory = {"mean": theory.mean, "variance": theory.moment(2, central=True),
                      "third_central": theory.moment(3, central=True)}
    return Comparison(l1, ks, moments_theory, dict(hist.moments), theory.contact_area(threshold),
                      hist.fraction_above(threshold), threshold)


def kolmogorov_distance(cdf: Callable, quantiles: Array, levels: Array, *, p_floor: float = 0.0,
                        zero_weight: float = 0.0) -> float:
    """``sup |F - F_field|`` over ``p >= p_floor``: a CDF ``cdf`` against a field's empirical CDF given by its quantile
    function (``quantiles`` at ``levels``). At each distinct quantile value ``x`` the empirical CDF jumps from about the
    first to the last level whose quantile is ``x`` (ties: the delta peak at 0); both sides of the jump are compared
    with ``cdf`` on the same side (``cdf`` includes a weight ``zero_weight`` in a delta peak at ``p = 0``).  Resolution:
    one level step, ``1/(len(levels) - 1)``."""
    uniq, first = np.unique(quantiles, return_index=True)
    last = np.searchsorted(quantiles, uniq, side="right") - 1
    keep = uniq >= p_floor
    uniq, first, last = uniq[keep], first[keep], last[keep]
    f_after = np.asarray(cdf(uniq), dtype=float)
    f_before = f_after - np.where(uniq == 0.0, float(zero_weight), 0.0)
    before = np.maximum(first - 1, 0)
    k = int(np.searchsorted(quantiles, p_floor, side="right")) - 1
    d_floor = abs(float(cdf(p_floor)) - (float(levels[k]) if k >= 0 else 0.0))
    if uniq.size == 0:
        return d_floor
    return float(max(d_floor, np.max(np.abs(f_after - levels[last])), np.max(np.abs(f_before - levels[before]))))


def kolmogorov_between(first: SimulatedHistogram, second: SimulatedHistogram) -> float:
    """Kolmogorov distance between two simulated fields (e.g. two surface seeds).

    ``sup |F_1 - F_2|`` over ``p >= first.edges[1]`` (the same resolution as :func:`compare`):
    :func:`kolmogorov_distance` of each field's quantiles against the other's empirical CDF (linear between its
    quantiles), the larger of the two.  Used as the realization scatter a theory can be expected to reach."""
    if first.quantiles is None or second.quantiles is None:
        raise ValueError("both histograms need stored quantiles (SimulatedHistogram.from_pressures keeps them)")
    p_floor = float(first.edges[1])

    def empirical(h: SimulatedHistogram) -> Callable:
        return lambda x: np.interp(x, h.quantiles, h.quantile_levels, left=0.0, right=1.0)

    return max(kolmogorov_distance(empirical(second), first.quantiles, first.quantile_levels, p_floor=p_floor),
               kolmogorov_distance(empirical(first), second.quantiles, second.quantile_levels, p_floor=p_floor))
