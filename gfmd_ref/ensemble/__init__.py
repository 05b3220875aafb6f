"""GFMD ensembles: runs on Dask (:mod:`.run`), the store of one file per case (:mod:`.store`),
reductions with error bars (:mod:`.stats`) and the bundled data (:mod:`.data`). Dask is imported
only when a run needs a cluster (``pip install "diffusion-pr[ensemble]"``)."""
from .data import bundled_ensemble, write_bundle
from .run import EnsembleRun, EnsembleSurface, FIG1_SURFACE, code_version, ingest_fields, run_ensemble
from .store import Ensemble, EnsembleGroup, EnsembleRecord, load_ensemble, reduce_pressure_field

__all__ = ["run_ensemble", "ingest_fields", "EnsembleRun", "EnsembleSurface", "FIG1_SURFACE", "code_version",
           "load_ensemble", "Ensemble", "EnsembleGroup", "EnsembleRecord", "reduce_pressure_field",
           "bundled_ensemble", "write_bundle"]
