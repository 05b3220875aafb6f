"""Matplotlib helpers: each takes an optional ``ax`` and returns it.  Pressures are drawn in the units the
result was computed in (those of ``p0`` and ``E*``; name them with ``units=``)."""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

#: Decades of density a log plot shows below its body's peak by default.
DECADES = 6.0

#: The pressure axis spans the continuous part's quantiles from QUANTILE to 1 - QUANTILE.
QUANTILE = 1e-4


def _axes(ax: Any, units: Optional[str]) -> Any:
    """``ax`` (a new figure in constrained layout, whose labels survive savefig, if None), labelled in ``units``."""
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(5.0, 3.6), layout="constrained")
    ax.set_xlabel(f"pressure p [{units or 'units of p0'}]")
    ax.set_ylabel(f"Pr(p) [1 / ({units or 'units of p0'})]")
    return ax


def body_range(result: Any, quantile: float = QUANTILE) -> tuple[float, float]:
    """The continuous part's ``quantile`` and ``1 - quantile`` quantiles (pressure), from the cdf at the edges or
    nodes."""
    x = np.asarray(result.edges if result.edges is not None else result.p, dtype=float)
    x = np.unique(np.concatenate(([0.0], x[x > 0])))
    share = np.asarray(result.cdf(x), dtype=float) - float(result.zero_weight)
    total = share[-1] if share[-1] > 0 else 1.0
    lo, hi = np.interp([quantile * total, (1.0 - quantile) * total], np.maximum.accumulate(share), x)
    return float(lo), float(hi)


def plot_distribution(result: Any, ax: Optional[Any] = None, *, log: bool = True, label: Optional[str] = None,
                      decades: float = DECADES, logp: Optional[bool] = None, units: Optional[str] = None,
                      **kwargs: Any) -> Any:
    """Plot the continuous part (:meth:`~diffusion_pr.result.PressureDistribution.pdf`) of a result.

    Parameters
    ----------
    result : PressureDistribution
        What to plot (density in 1/pressure against pressure).
    ax : matplotlib Axes, optional
        Axes to draw on; a new figure (constrained layout) is made when omitted.
    log : bool
        Logarithmic density axis (the paper's Fig. 1 style), ``decades`` below the peak.
    label : str, optional
        Legend label; defaults to the closure, the backend and the contact area at the result's threshold.
    logp : bool, optional
        Logarithmic pressure axis; default where :func:`body_range` spans more than 3 decades.  The axis spans
        :func:`body_range` (from 0 where that is near); on axes holding curves it is widened, never narrowed.
    units : str, optional
        The pressure unit of the labels (default "units of p0": those ``p0`` and ``E*`` were given in).

    Returns
    -------
    matplotlib Axes
    """
    fresh = ax is None or not ax.get_lines()
    ax = _axes(ax, units)
    if label is None:
        label = f"{result.diagnostics.get('closure', 'second_order')}, {result.backend}"
        if result.contact_threshold is not None:
            label += f" (a_r = {result.contact_area():.4f}, p > {result.contact_threshold:.3g})"
    lo, hi = body_range(result)
    logp = bool(hi > 1e3 * lo) if logp is None else logp
    if not logp and lo < 0.25 * hi:
        lo = 0.0
    q = np.geomspace(lo, hi, 2001) if logp else np.linspace(lo, hi, 2001)
    if result.edges is not None:
        q = np.union1d(q, result.edges[(result.edges > lo) & (result.edges < hi)])
    density = np.asarray(result.pdf(q), dtype=float)
    ax.plot(q, np.where(density > 0.0, density, np.nan) if log else density, label=label, **kwargs)
    if logp:
        ax.set_xscale("log")
    if not fresh:
        x0, x1 = ax.get_xlim()
        lo, hi = min(lo, x0), max(hi, x1)
    ax.set_xlim(lo, hi)
    if log:
        ax.set_yscale("log")
        top = 2.0 * float(np.nanmax(density))
        y0, y1 = (top * 0.5 * 10.0 ** -float(decades), top) if fresh else ax.get_ylim()
        ax.set_ylim(min(y0, top * 0.5 * 10.0 ** -float(decades)), max(y1, top))
    return ax


def plot_histogram(centers: Any, density: Any, ax: Optional[Any] = None, *, log: bool = True,
                   label: Optional[str] = None, units: Optional[str] = None, **kwargs: Any) -> Any:
    """Plot a simulated pressure histogram as symbols (``ax`` in, ``ax`` out; ``units`` as
    :func:`plot_distribution`)."""
    ax = _axes(ax, units)
    density = np.asarray(density, dtype=float)
    ax.plot(centers, np.where(density > 0.0, density, np.nan) if log else density, label=label,
            **{"marker": "o", "linestyle": "none", "markersize": 3, **kwargs})
    if log:
        ax.set_yscale("log")
    return ax
