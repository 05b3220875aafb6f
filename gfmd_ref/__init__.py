"""gfmd_ref: Green's-function molecular dynamics reference solver.

A standalone (numpy, scipy, numba) solver for an elastic half-space pressed on a
rigid, periodic rough surface, with hard-wall or exponential repulsion. It never
imports :mod:`diffusion_pr`.

Public API: :func:`self_affine_surface`, :class:`HardWall`,
:class:`ExponentialRepulsion`, :func:`solve_contact` (-> :class:`ContactResult`),
:class:`ConvergenceWarning`, :func:`pressure_histogram`, :func:`fig1_surface`,
:func:`warm_up_fft`; ensembles on Dask: :func:`run_ensemble`, :func:`load_ensemble`,
:func:`bundled_ensemble` (see :mod:`gfmd_ref.ensemble`).
"""
from ._fft import fft_pair
from .ensemble import EnsembleSurface, ingest_fields, run_ensemble
from .ensemble_data import bundled_ensemble
from .ensemble_store import load_ensemble
from .histogram import PressureHistogram, pressure_histogram
from .interactions import ExponentialRepulsion, HardWall
from .scene import FIG1, fig1_surface
from .solver import N_SINGLE_ARRAYS, N_WORK_ARRAYS, ContactResult, ConvergenceWarning, solve_contact
from .surface import self_affine_surface, spectral_rms_slope

__all__ = [
    "self_affine_surface",
    "spectral_rms_slope",
    "HardWall",
    "ExponentialRepulsion",
    "solve_contact",
    "ContactResult",
    "ConvergenceWarning",
    "pressure_histogram",
    "PressureHistogram",
    "fig1_surface",
    "FIG1",
    "warm_up_fft",
    "run_ensemble",
    "load_ensemble",
    "bundled_ensemble",
    "ingest_fields",
    "EnsembleSurface",
]


def warm_up_fft(n: int) -> float:
    """Plan the FFTs for ``(n, n)`` grids now; returns the seconds spent (0 if done).

    The first :func:`solve_contact` on a new grid size pays this planning
    (about 1-2 s at 1024^2 with FFTW, including the plans of the hard-wall solver's
    work arrays, double and single precision; nothing with scipy.fft); later calls in
    the same process reuse the plans, and later processes read FFTW's wisdom from
    :func:`gfmd_ref._fft.wisdom_path` (0.9 s -> 0.17 s at 512^2).
    """
    pair, planning = fft_pair((int(n), int(n)))
    return planning + pair.make_work_arrays(N_WORK_ARRAYS, single=N_SINGLE_ARRAYS)
