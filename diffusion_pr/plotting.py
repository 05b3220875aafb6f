"""Matplotlib helpers: each takes an optional ``ax`` and returns it."""
from __future__ import annotations

from typing import Any, Optional

import numpy as np


def _axes(ax: Any) -> Any:
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(5.0, 3.6))
    return ax


#: Decades of density a log plot shows below its peak by default (a solver's far
#: tail can reach 1e-300; drawing all of it would squash the visible curve).
DECADES = 6.0


def _readable_limits(ax: Any, p: np.ndarray, density: np.ndarray, decades: float, fresh: bool) -> None:
    """y from ``peak * 10**-decades`` to twice the peak, x up to where the density is last that high."""
    positive = density[np.isfinite(density) & (density > 0)]
    if positive.size == 0:
        return
    top = float(positive.max())
    bottom = max(float(positive.min()), top * 10.0 ** (-decades))
    visible = np.nonzero(np.isfinite(density) & (density >= bottom))[0]
    x_hi = float(p[visible[-1]]) if visible.size else float(p[-1])
    if not fresh:  # several curves on one axes: widen, never cut an earlier curve
        lo, hi = ax.get_ylim()
        bottom, top = min(bottom, lo), max(2.0 * top, hi) / 2.0
        x_hi = max(x_hi, ax.get_xlim()[1])
    if bottom < top:
        ax.set_ylim(bottom, 2.0 * top)
    if x_hi > 0:
        ax.set_xlim(0.0, 1.02 * x_hi)


def plot_distribution(result: Any, ax: Optional[Any] = None, *, log: bool = True, label: Optional[str] = None,
                      decades: float = DECADES, **kwargs: Any) -> Any:
    """Plot the continuous part of a :class:`~diffusion_pr.result.PressureDistribution`.

    Parameters
    ----------
    result : PressureDistribution
        What to plot (density in 1/pressure against pressure).
    ax : matplotlib Axes, optional
        Axes to draw on; a new figure is made when omitted.
    log : bool
        Logarithmic density axis (the paper's Fig. 1 style).
    label : str, optional
        Legend label; defaults to the backend name and the contact fraction.
    decades : float
        With ``log``, the y-axis spans this many decades below the peak
        density and the x-axis ends where the density drops below that
        (widened, never narrowed, when the axes already holds curves).

    Returns
    -------
    matplotlib Axes
    """
    fresh = ax is None or not ax.get_lines()
    ax = _axes(ax)
    if label is None:
        closure = result.diagnostics.get("closure", "second_order")
        label = f"{closure}, {result.backend}"
        if result.contact_threshold is not None:
            label += f" (a_r = {result.contact_area():.4f}, p > {result.contact_threshold:.3g})"
    density = np.asarray(result.density, dtype=float)
    if log:
        density = np.where(density > 0.0, density, np.nan)
    ax.plot(result.p, density, label=label, **kwargs)
    if log:
        ax.set_yscale("log")
        _readable_limits(ax, np.asarray(result.p, dtype=float), density, float(decades), fresh)
    ax.set_xlabel("pressure p (units of E*)")
    ax.set_ylabel("Pr(p) (1 / pressure)")
    return ax


def plot_histogram(centers: Any, density: Any, ax: Optional[Any] = None, *, log: bool = True,
                   label: Optional[str] = None, **kwargs: Any) -> Any:
    """Plot a simulated pressure histogram as symbols (``ax`` in, ``ax`` out)."""
    ax = _axes(ax)
    density = np.asarray(density, dtype=float)
    if log:
        density = np.where(density > 0.0, density, np.nan)
    kwargs.setdefault("marker", "o")
    kwargs.setdefault("linestyle", "none")
    kwargs.setdefault("markersize", 3)
    ax.plot(centers, density, label=label, **kwargs)
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("pressure p (units of E*)")
    ax.set_ylabel("Pr(p) (1 / pressure)")
    return ax
