"""gfmd_ref: Green's-function molecular dynamics reference solver.

A standalone (numpy, scipy, numba) solver for an elastic half-space pressed on a
rigid, periodic rough surface, with hard-wall or exponential repulsion (docs/gfmd.md).
It never imports :mod:`diffusion_pr`. Ensembles (:mod:`gfmd_ref.ensemble`) need Dask
for cluster runs (``pip install "diffusion-pr[ensemble]"``).
"""
from .ensemble import EnsembleSurface, bundled_ensemble, ingest_fields, load_ensemble, run_ensemble
from .histogram import PressureHistogram, pressure_histogram
from .interactions import ExponentialRepulsion, HardWall
from .scene import FIG1, fig1_surface
from .solvers import EXP_CONTACT_THRESHOLD, ContactResult, ConvergenceWarning, solve_contact
from .surface import self_affine_surface, spectral_rms_slope

__all__ = ["self_affine_surface", "spectral_rms_slope", "HardWall", "ExponentialRepulsion", "solve_contact",
           "ContactResult", "ConvergenceWarning", "EXP_CONTACT_THRESHOLD", "pressure_histogram", "PressureHistogram",
           "fig1_surface", "FIG1", "run_ensemble", "load_ensemble", "bundled_ensemble", "ingest_fields",
           "EnsembleSurface"]
