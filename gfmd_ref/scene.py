"""The paper's Fig. 1 scene at any grid size (Müser, Phys. Rev. Lett. 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504): wavelengths 32 ... 1024 grid spacings, H = 0.3, rms
slope 0.031, E* = 8/3, p0 = 0.004. :mod:`gfmd_ref` never imports :mod:`diffusion_pr`, so it
keeps its own copy of these numbers in :data:`FIG1`; ``diffusion_pr.paper`` holds the
package's copy (with the quotes) and the test suite checks that the two agree.
"""
from __future__ import annotations

import math

from ._validation import check_int, check_positive
from .surface import self_affine_surface

#: Fig. 1 parameters: H, rms slope, E*, p0, the number of waves per period of the
#: shortest wavelength (q_max = 32 q_min), and the paper's cell side in grid spacings.
FIG1 = dict(hurst=0.3, rms_slope=0.031, E_star=8.0 / 3.0, mean_pressure=0.004, n_waves=32, length=1024.0)


def fig1_surface(n: int = 1024, seed=1):
    """Fig. 1 surface on an ``n x n`` grid (``length = n``, ``q_min = 2 pi/n``,
    ``q_max = 32 q_min``, ``H = 0.3``, rms slope 0.031). Returns ``(heights, length)``.
    ``n >= 64``: the shortest wavelength ``n/32`` must span two grid points.

    Lengths are in grid spacings of *this* grid (``length = n``).  The contact
    problem is scale invariant (fixed rms slope, E* and p0), so this is the
    paper's ``1024^2`` system scaled by ``n / 1024``; a wall range given in the
    paper's unit converts with :func:`zeta_on_grid`.
    """
    n = check_int("n", n, minimum=2)
    if n < 2 * FIG1["n_waves"]:
        raise ValueError(f"n must be >= {2 * FIG1['n_waves']}: the Fig. 1 roughness's shortest wavelength, "
                         f"L/{FIG1['n_waves']}, needs 2 grid points (Nyquist); got n={n}")
    return band_surface(n, float(n), FIG1["hurst"], FIG1["rms_slope"], FIG1["n_waves"], seed), float(n)


def band_surface(n: int, length: float, hurst: float, rms_slope: float, n_waves: int, seed):
    """A self-affine surface of one scene family: wavelengths ``length`` down to
    ``length / n_waves`` (``q_min = 2 pi/length``, ``q_max = n_waves q_min``), Hurst
    exponent ``hurst`` and rms slope ``rms_slope`` (:func:`~gfmd_ref.self_affine_surface`)."""
    qmin = 2.0 * math.pi / length
    return self_affine_surface(n, length=length, hurst=hurst, q_min=qmin, q_max=n_waves * qmin,
                               rms_slope=rms_slope, seed=seed)


def zeta_on_grid(zeta: float, n: int) -> float:
    """A wall range in grid spacings of the paper's 1024^2 system, converted to
    grid spacings of the ``n x n`` grid of :func:`fig1_surface` (``zeta * n / 1024``)."""
    return check_positive("zeta", zeta) * check_int("n", n, minimum=2) / FIG1["length"]
