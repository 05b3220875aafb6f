"""The paper's Fig. 1 scene (SPEC sections 2 and 6) at any grid size."""
from __future__ import annotations

import math

from .surface import self_affine_surface

#: Fig. 1 parameters: grid spacing is the length unit, L = n, wavelengths L ... L/32.
FIG1 = dict(hurst=0.3, rms_slope=0.031, E_star=8.0 / 3.0, mean_pressure=0.004, n_waves=32)


def fig1_surface(n: int = 1024, seed=1):
    """Fig. 1 surface on an ``n x n`` grid (``length = n``, ``q_min = 2 pi/n``,
    ``q_max = 32 q_min``, ``H = 0.3``, rms slope 0.031). Returns ``(heights, length)``."""
    length = float(n)
    qmin = 2.0 * math.pi / length
    h = self_affine_surface(
        n,
        length=length,
        hurst=FIG1["hurst"],
        q_min=qmin,
        q_max=FIG1["n_waves"] * qmin,
        rms_slope=FIG1["rms_slope"],
        seed=seed,
    )
    return h, length
