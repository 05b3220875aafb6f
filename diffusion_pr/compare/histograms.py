"""A simulated pressure field as a histogram (:class:`gfmd_ref.PressureHistogram`, also named
``SimulatedHistogram`` here) and a theory's bin averages.

Pressures in any unit shared by theory and simulation; densities in 1/pressure."""
from __future__ import annotations

from typing import Any

import numpy as np
from gfmd_ref.histogram import PressureHistogram
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


#: the one histogram type of a simulated pressure field, shared with the GFMD reference (which never imports
#: diffusion_pr): :class:`gfmd_ref.PressureHistogram`
SimulatedHistogram = PressureHistogram


def bin_averaged_density(theory: Any, edges: ArrayLike) -> Array:
    """Average of a theory's continuous density over each bin (1 / pressure).

    Uses the theory's cumulative distribution, so narrow features are integrated exactly rather than sampled at bin
    centres; the ``delta(p)`` peak is excluded."""
    edges = np.asarray(edges, dtype=float)
    cdf = np.asarray(theory.cdf(edges), dtype=float)
    # theory.cdf includes zero_weight for p >= 0; differences cancel it except
    # across p = 0 itself, which no bin here straddles (edges[0] >= 0).
    return np.diff(cdf) / np.diff(edges)
