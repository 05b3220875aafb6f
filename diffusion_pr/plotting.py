"""Matplotlib helpers: each takes an optional ``ax`` and returns it."""
from __future__ import annotations

from typing import Any, Optional

import numpy as np


def _axes(ax: Any) -> Any:
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(5.0, 3.6))
    return ax


def plot_distribution(result: Any, ax: Optional[Any] = None, *, log: bool = True, label: Optional[str] = None,
                      **kwargs: Any) -> Any:
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

    Returns
    -------
    matplotlib Axes
    """
    ax = _axes(ax)
    if label is None:
        closure = result.diagnostics.get("closure", "second_order")
        label = f"{closure}, {result.backend} (a_r = {result.contact_fraction:.4f})"
    density = np.asarray(result.density, dtype=float)
    if log:
        density = np.where(density > 0.0, density, np.nan)
    ax.plot(result.p, density, label=label, **kwargs)
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("pressure p")
    ax.set_ylabel("Pr(p)")
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
    ax.set_xlabel("pressure p")
    ax.set_ylabel("Pr(p)")
    return ax
