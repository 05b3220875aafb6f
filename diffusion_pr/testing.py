"""pytest helpers: a theory against GFMD data within the data's own noise, and seeded surfaces.

Copy and adapt (lengths in grid spacings, pressures in the paper's reduced unit, in which E* = 8/3)::

    import gfmd_ref, diffusion_pr as dp
    from diffusion_pr.testing import assert_matches_gfmd, seeded_surface  # noqa: F401 (the fixture)

    def test_my_closure_matches_gfmd(seeded_surface):
        s = seeded_surface(n=128, seed=3)                  # heights, length, spectrum of one seeded surface
        gfmd = gfmd_ref.solve_contact(s.heights, length=s.length, E_star=8/3, mean_pressure=0.004,
                                      interaction=gfmd_ref.ExponentialRepulsion(0.5), tol=1e-6)
        theory = dp.pressure_distribution(s.spectrum, E_star=8/3, mean_pressure=0.004, zeta=0.5,
                                          closure="local_g1_shell_balanced")
        assert_matches_gfmd(theory, gfmd, k_noise=3)

The noise is the bootstrap noise of the data themselves: of the seeds of an ensemble, of 4 x 4 spatial blocks of
a field (each block a pseudo-seed; blocks much larger than the roughness's shortest wavelength are nearly
independent), or of a histogram's stored quantiles taken as independent values (no spatial layout: it
underestimates the noise of a correlated field; prefer the field)."""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Optional

import numpy as np
import pytest

from .compare import EnsembleComparison, compare_ensemble

__all__ = ["assert_matches_gfmd", "gfmd_comparison", "SeededSurface", "seeded_surface"]

#: blocks per side of a single field's block bootstrap
BLOCKS = 4


def _records(groups: list, p0: float, threshold: float) -> list:
    """Each group of pressures as a pseudo-seed in the shape :func:`~diffusion_pr.compare.compare_ensemble` reads."""
    levels = np.linspace(0.0, 1.0, 1025)
    out = []
    for k, v in enumerate(np.asarray(g, dtype=float).ravel() for g in groups):
        c = v - v.mean()
        out.append(SimpleNamespace(levels=levels, quantiles=np.quantile(v, levels), seed=k, mean_pressure=p0,
                                   contact_threshold=threshold, contact_fraction=float(np.mean(v > threshold)),
                                   mean=float(v.mean()), variance=float(np.mean(c * c)),
                                   third_central=float(np.mean(c**3))))
    return out


def _blocks(field: np.ndarray) -> list:
    bx, by = field.shape[0] // BLOCKS, field.shape[1] // BLOCKS
    return [field[i * bx:(i + 1) * bx, j * by:(j + 1) * by] for i in range(BLOCKS) for j in range(BLOCKS)]


def gfmd_comparison(theory: Any, gfmd: Any, *, p_min: Optional[float] = None, n_boot: int = 400,
                    seed: int = 0) -> EnsembleComparison:
    """:func:`~diffusion_pr.compare.compare_ensemble` of ``theory`` against GFMD data of any form.

    Parameters
    ----------
    theory : PressureDistribution
        Its ``contact_threshold`` (pressure) counts the contact area on both sides.
    gfmd : ensemble, ContactResult, pressure field(s) or PressureHistogram
        A group or sequence of ensemble records (seeds); a :func:`gfmd_ref.solve_contact` result or a 2-d
        pressure field [pressure] (block bootstrap), or a sequence of them (one pseudo-seed per field); a
        :class:`gfmd_ref.PressureHistogram` with stored quantiles.
    p_min, n_boot, seed
        As in :func:`~diffusion_pr.compare.compare_ensemble` (``p_min`` default ``p0/20``).
    """
    p0, threshold = float(theory.mean_pressure), float(theory.contact_threshold or 0.0)
    if hasattr(gfmd, "records") or (isinstance(gfmd, (list, tuple)) and gfmd and hasattr(gfmd[0], "quantiles")):
        records = gfmd
    elif getattr(gfmd, "quantiles", None) is not None:  # a histogram: its quantiles as independent values
        values = np.random.default_rng(seed).permutation(np.asarray(gfmd.quantiles, dtype=float))
        records = _records(np.array_split(values, BLOCKS * BLOCKS), p0, threshold)
    else:
        fields = [getattr(f, "pressure", f) for f in (gfmd if isinstance(gfmd, (list, tuple)) else [gfmd])]
        fields = [np.asarray(f, dtype=float) for f in fields]
        if any(f.ndim != 2 or not np.all(np.isfinite(f)) for f in fields):
            raise ValueError("gfmd must be an ensemble (records), a ContactResult, finite 2-d pressure field(s) or a "
                             f"PressureHistogram with quantiles; got {type(gfmd).__name__}")
        records = _records(fields if len(fields) > 1 else _blocks(fields[0]), p0, threshold)
    return compare_ensemble(theory, records, p_min=p_min, n_boot=n_boot, seed=seed)


def assert_matches_gfmd(theory: Any, gfmd: Any, *, k_noise: float = 3.0, p_min: Optional[float] = None,
                        n_boot: int = 400, seed: int = 0) -> EnsembleComparison:
    """Assert that the Kolmogorov distance ``K`` of ``theory`` from the GFMD data is at most ``k_noise`` times the
    data's own bootstrap noise (:func:`gfmd_comparison`; arguments as there); return the comparison.

    Raises
    ------
    AssertionError
        Naming ``K``, the noise, the pressure where the CDFs differ most with both values, and the contact areas.
    """
    c = gfmd_comparison(theory, gfmd, p_min=p_min, n_boot=n_boot, seed=seed)
    if c.kolmogorov > k_noise * c.noise_bootstrap:
        i = int(np.argmax(np.abs(c.cdf_theory - c.cdf_pool)))
        raise AssertionError(
            f"theory does not match GFMD: K = {c.kolmogorov:.4f} > {k_noise:g} x noise {c.noise_bootstrap:.4f} "
            f"(bootstrap over {c.n_seeds} seeds or blocks, p >= {c.p_min:.4g}); the CDFs differ most at "
            f"p = {c.p[i]:.4g}: theory {c.cdf_theory[i]:.4f}, GFMD {c.cdf_pool[i]:.4f}; contact area "
            f"(p > {c.threshold:.3g}): theory {c.contact_fraction_theory:.4f}, GFMD {c.contact_fraction_gfmd:.4f}")
    return c


@dataclass(frozen=True)
class SeededSurface:
    """A periodic self-affine surface: ``heights`` [length] on ``n x n`` points, its period ``length`` [length]
    and its own :class:`~diffusion_pr.spectra.DiscreteSpectrum`."""

    heights: np.ndarray
    length: float
    spectrum: Any


@pytest.fixture
def seeded_surface() -> Any:
    """Factory ``seeded_surface(n=64, seed=1, hurst=0.3, rms_slope=0.031, lambda_min=None)`` (the paper's H and
    slope): a :class:`SeededSurface` with ``length = n`` (grid spacings) and roughness from ``n`` down to
    ``lambda_min`` (default ``n/8``), from :func:`gfmd_ref.self_affine_surface` (same seed, same surface)."""
    from gfmd_ref import self_affine_surface

    from .paper import HURST, RMS_SLOPE
    from .spectra import DiscreteSpectrum

    def make(n: int = 64, seed: int = 1, hurst: float = HURST, rms_slope: float = RMS_SLOPE,
             lambda_min: Optional[float] = None) -> SeededSurface:
        length = float(n)
        h = self_affine_surface(n, length=length, hurst=hurst, q_min=2 * np.pi / length,
                                q_max=2 * np.pi / (lambda_min or n / 8), rms_slope=rms_slope, seed=seed)
        return SeededSurface(h, length, DiscreteSpectrum.from_heights(h, length))

    return make
