"""The paper's numbers, in one place, pinned to the paper's own words.

Source: M. H. Müser, *A rigorous, field-theoretical approach to the contact mechanics of rough elastic solids*, Phys.
Rev. Lett. 100, 055504 (2008), doi:10.1103/PhysRevLett.100.055504.  The Fig. 1 paragraph reads (quoted verbatim, LaTeX
as in the text the project works from):

    "The system that was investigated has roughness on wavelengths $32 \\leq \\lambda \\leq 1024$, the Hurst roughness
    exponent is $H = 0.3$, and the root-mean-square slope is 0.031. Furthermore, $E' = 8/3$ and $p_0 = 0.004$ in the
    same units. ζ is varied between 0.001 and 4. The unit for length scale is defined by the distance between two grid
    points in the numerical solution."

    "Values of p_c used for our calculations were $p_c = 0.0027$ for all curves with $\\zeta \\geq 0.25$ and $p_c =
    0.0082$ [0.0068] for $\\zeta = 0.01$ [0.001]. These three values for p_c are the only adjustable coefficients used
    in Fig. 1."

The same sentences are kept as strings in :data:`QUOTES`; the test suite
(``tests/diffusion_pr/test_paper.py``) parses every constant below back out of
them, so a constant cannot drift from the paper without a failing test.

One number here is **not** the paper's: :data:`EXP_CONTACT_THRESHOLD`.  The paper shows pressure histograms only; to
compare "contact fractions" of an exponential (soft) wall, whose pressure is never exactly zero, this project counts a
point as in contact when ``p > 0.01 p0`` (the definition of :attr:`gfmd_ref.ContactResult.contact_fraction`,
``gfmd_ref.EXP_CONTACT_THRESHOLD``; see the docs page ``gfmd``).  :mod:`gfmd_ref` does not import :mod:`diffusion_pr`,
so it keeps its own copy; a test checks that the two agree.

Units are the paper's: lengths in grid spacings of the ``1024 x 1024`` system,
pressures in the units of ``E'`` (= ``E*``, the contact modulus)."""
from __future__ import annotations

import math

__all__ = [
    "DOI", "QUOTES", "E_STAR", "MEAN_PRESSURE", "HURST", "RMS_SLOPE", "LENGTH", "LAMBDA_MIN", "N_WAVES",
    "ZETA_RANGE", "CUTOFF_PRESSURE_LARGE_ZETA", "LARGE_ZETA", "PAPER_CUTOFF_PRESSURES", "EXP_CONTACT_THRESHOLD",
    "FIG1_SCENE", "cutoff_pressure", "contact_threshold",
]

#: Digital object identifier of the paper.
DOI = "10.1103/PhysRevLett.100.055504"

#: The paper's sentences the constants below come from (verbatim).
QUOTES: dict[str, str] = {
    "system": (
        "The system that was investigated has roughness on wavelengths $32 \\leq \\lambda \\leq 1024$, "
        "the Hurst roughness exponent is $H = 0.3$, and the root-mean-square slope is 0.031. "
        "Furthermore, $E' = 8/3$ and $p_0 = 0.004$ in the same units. ζ is varied between 0.001 and 4. "
        "The unit for length scale is defined by the distance between two grid points in the numerical solution."
    ),
    "cutoffs": (
        "Values of p_c used for our calculations were $p_c = 0.0027$ for all curves with $\\zeta \\geq 0.25$ "
        "and $p_c = 0.0082$ [0.0068] for $\\zeta = 0.01$ [0.001]. These three values for p_c are the only "
        "adjustable coefficients used in Fig. 1."
    ),
}

#: Contact modulus ``E' = E / (1 - nu^2)`` ("E' = 8/3"), units of pressure.
E_STAR: float = 8.0 / 3.0
#: Mean pressure ``p0`` ("p_0 = 0.004"), in the unit of :data:`E_STAR` (the paper's reduced units).
MEAN_PRESSURE: float = 0.004
#: Hurst exponent ("H = 0.3").
HURST: float = 0.3
#: Root-mean-square slope ("the root-mean-square slope is 0.031"), dimensionless.
RMS_SLOPE: float = 0.031
#: Period of the cell = longest wavelength ("32 <= lambda <= 1024"), grid spacings.
LENGTH: float = 1024.0
#: Shortest wavelength ("32 <= lambda"), grid spacings.
LAMBDA_MIN: float = 32.0
#: Shortest wavelength's number of waves per period: ``q_max / q_min = LENGTH / LAMBDA_MIN = 32``.
N_WAVES: int = 32
#: Range of the exponential wall's decay length zeta ("varied between 0.001 and 4"), grid spacings.
ZETA_RANGE: tuple[float, float] = (0.001, 4.0)
#: "p_c = 0.0027 for all curves with zeta >= 0.25".
CUTOFF_PRESSURE_LARGE_ZETA: float = 0.0027
#: The zeta from which on the paper uses :data:`CUTOFF_PRESSURE_LARGE_ZETA`.
LARGE_ZETA: float = 0.25
#: The paper's fitted cutoff pressures by zeta: "p_c = 0.0082 [0.0068] for zeta = 0.01 [0.001]",
#: and 0.0027 at 0.25 (the smallest zeta of the "zeta >= 0.25" group).
PAPER_CUTOFF_PRESSURES: dict[float, float] = {0.001: 0.0068, 0.01: 0.0082, LARGE_ZETA: CUTOFF_PRESSURE_LARGE_ZETA}

#: Exponential wall: a point is "in contact" when ``p > EXP_CONTACT_THRESHOLD * p0`` (this
#: project's convention, not the paper's; equal to ``gfmd_ref.EXP_CONTACT_THRESHOLD``).
EXP_CONTACT_THRESHOLD: float = 0.01

#: The Fig. 1 scene as keyword arguments (lengths in grid spacings of the 1024^2 system,
#: ``q = 2 pi / lambda``).
FIG1_SCENE: dict[str, float] = {"length": LENGTH, "hurst": HURST, "q_min": 2.0 * math.pi / LENGTH,
                                 "q_max": 2.0 * math.pi / LAMBDA_MIN, "rms_slope": RMS_SLOPE, "E_star": E_STAR,
                                 "mean_pressure": MEAN_PRESSURE}


def cutoff_pressure(zeta: float) -> float:
    """The paper's cutoff pressure ``p_c`` (in the unit of :data:`E_STAR`): 0.0027 for ``zeta >= 0.25``, 0.0082 at
    ``zeta = 0.01``, 0.0068 at ``zeta = 0.001``; for a ``zeta`` the paper does not name (e.g. 0.1), the log-nearest
    named one's.

    Parameters
    ----------
    zeta : float
        Decay length of the exponential wall (grid spacings), ``> 0``.
    """
    try:
        if isinstance(zeta, (str, bytes, bool)):
            raise TypeError
        z = float(zeta)
    except (TypeError, ValueError):
        raise ValueError(f"zeta must be a finite number > 0; got zeta={zeta!r}") from None
    if not math.isfinite(z) or z <= 0:
        raise ValueError(f"zeta must be a finite number > 0; got zeta={zeta!r}")
    if z >= LARGE_ZETA:
        return CUTOFF_PRESSURE_LARGE_ZETA
    nearest = min(PAPER_CUTOFF_PRESSURES, key=lambda named: abs(math.log(named) - math.log(z)))
    return PAPER_CUTOFF_PRESSURES[nearest]


def contact_threshold(zeta: float | None, mean_pressure: float = MEAN_PRESSURE) -> float:
    """Pressure above which a point counts as in contact (units of pressure). ``0`` for the hard wall (``zeta`` None or
    0: contact means ``p > 0``), ``EXP_CONTACT_THRESHOLD * mean_pressure`` for an exponential wall."""
    return 0.0 if zeta is None or zeta == 0 else EXP_CONTACT_THRESHOLD * float(mean_pressure)
