"""Theory against simulation: a simulated pressure field (from :mod:`gfmd_ref` or any other contact solver) enters as
a :data:`SimulatedHistogram` (gfmd_ref's numpy-only histogram type); distances in
:mod:`~diffusion_pr.compare.distances`, curvatures and fits in :mod:`~diffusion_pr.compare.fits`, ensembles of seeds in
:mod:`~diffusion_pr.compare.ensemble`."""
from .distances import (Comparison, SimulatedHistogram, bin_averaged_density, compare, kolmogorov_between,
                        kolmogorov_distance)
from .ensemble import EnsembleComparison, compare_ensemble
from .fits import LOG_FLOOR, CutoffFit, fit_cutoff_pressure, fit_tail_pressure, log_density_curvature, tail_curvatures

__all__ = ["SimulatedHistogram", "bin_averaged_density", "Comparison", "compare", "kolmogorov_distance",
           "kolmogorov_between", "log_density_curvature", "tail_curvatures", "LOG_FLOOR", "CutoffFit",
           "fit_cutoff_pressure", "fit_tail_pressure", "EnsembleComparison", "compare_ensemble"]
