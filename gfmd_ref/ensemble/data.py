"""Bundled ensembles: compact per-seed quantiles shipped as package data.

A bundle is one compressed ``.npz`` in ``gfmd_ref/data/`` made from one or more stores
by :func:`write_bundle` (``gfmd-ref ensemble-bundle``). Per record it keeps the case
parameters, the convergence provenance, the moments, sd, skewness, contact fraction and
zero weight (float64, from the full field) and the quantiles at :data:`BUNDLE_LEVELS`
(``i/1024``: a Kolmogorov distance read from them is exact to one level step, 9.8e-4) as
float32 (pressures below 1.2e-38 become 0); per surface (seed) the exact shell spectrum.
"""
from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .store import Ensemble, EnsembleRecord, _jsonable, case_key, load_ensemble, now_iso

__all__ = ["BUNDLE_LEVELS", "BUNDLED_ENSEMBLES", "bundled_ensemble", "write_bundle"]

BUNDLE_LEVELS = np.linspace(0.0, 1.0, 1025)
#: names of the bundled ensembles and what they are.
BUNDLED_ENSEMBLES = {
    "fig1_n1024": "the paper's Fig. 1 scene at 1024^2 (H = 0.3, rms slope 0.031, E* = 8/3, p0 = 0.004), "
                  "hard wall and zeta = 0.001 ... 4, tol 1e-6",
    "offscene_n512": "off-scene check at 512^2 (H = 0.7, rms slope 0.05, E* = 1, p0 = 0.005, wavelengths "
                     "L ... L/32), hard wall and zeta = 0.01, 0.1, 0.5, 2, seeds 1-16, tol 1e-6",
}
_SCAL = ("mean", "variance", "third_central", "sd", "skewness", "contact_fraction", "contact_threshold",
         "zero_weight")


def write_bundle(stores: Sequence[os.PathLike | str] | os.PathLike | str, out: os.PathLike | str, *, name: str,
                 command: str = "", regenerate: str = "", seeds=None) -> tuple:
    """Write the records of ``stores`` (only ``seeds`` if given) as a compact bundle;
    returns ``(path, bytes)``."""
    stores = [stores] if isinstance(stores, (str, os.PathLike)) else stores
    recs, infos = [], []
    for s in stores:
        e = load_ensemble(s)
        recs.extend(r for r in e.records if seeds is None or r.seed in set(seeds))
        infos.append(dict(store=str(s), runs=e.info.get("runs", [])))
    if not recs:
        raise ValueError(f"no record to bundle (stores {list(map(str, stores))}, seeds {seeds})")
    step = (len(recs[0].levels) - 1) // (len(BUNDLE_LEVELS) - 1)
    for r in recs:
        if not np.allclose(r.levels[::step], BUNDLE_LEVELS, rtol=0, atol=1e-15):
            raise ValueError(f"record {r.key}: its levels do not contain the bundle levels i/1024")
    if len({r.key for r in recs}) != len(recs):
        raise ValueError("the stores share cases: a bundle must not hold a case twice")
    surf_of, spectra, spec_off, rec_spec = {}, [], [0], []  # one spectrum per surface (n, seed, family, L)
    for r in recs:
        sk = (r.n, r.seed, json.dumps(r.params["surface"], sort_keys=True), r.length)
        if sk not in surf_of and r.spectrum_q is not None:
            surf_of[sk] = len(spectra)
            spectra.append((r.spectrum_q, r.spectrum_power, r.spectrum_multiplicity))
            spec_off.append(spec_off[-1] + r.spectrum_q.size)
        rec_spec.append(surf_of.get(sk, -1))
    spec_q, spec_p, spec_m = zip(*spectra) if spectra else ((np.zeros(0),), (np.zeros(0),), (np.zeros(0, np.int32),))
    arrays = dict(
        levels=BUNDLE_LEVELS,
        quantiles=np.array([r.quantiles[::step] for r in recs], dtype=np.float32),
        params=np.array([json.dumps(r.params, sort_keys=True) for r in recs]),
        provenance=np.array([_jsonable(dict(
            converged=r.converged, residual=r.provenance.get("residual"), iterations=r.provenance.get("iterations"),
            wall_time=r.provenance.get("wall_time"), method=r.provenance.get("method"),
            source=r.provenance.get("source"), code=r.provenance.get("code"),
            field_code=r.provenance.get("field_code"), command=r.provenance.get("command"))) for r in recs]),
        spectrum_index=np.array(rec_spec, dtype=np.int32),
        spectrum_q=np.concatenate(spec_q), spectrum_power=np.concatenate(spec_p),
        spectrum_multiplicity=np.concatenate(spec_m).astype(np.int32),
        spectrum_offsets=np.array(spec_off, dtype=np.int64),
        info=json.dumps(dict(name=name, created=now_iso(), command=command, regenerate=regenerate,
                             description=BUNDLED_ENSEMBLES.get(name, ""), stores=infos, n_records=len(recs))),
    )
    for k in _SCAL:
        arrays[k] = np.array([getattr(r, k) for r in recs], dtype=np.float64)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    os.replace(tmp, out)
    return out, out.stat().st_size


@functools.lru_cache(maxsize=8)
def _load_bundle(path: str) -> tuple:
    with np.load(path, allow_pickle=False) as z:
        d = {k: np.array(z[k]) for k in z.files}
    info = json.loads(str(d["info"]))
    levels = d["levels"]
    levels.setflags(write=False)
    off = d["spectrum_offsets"]
    recs = []
    for i in range(d["quantiles"].shape[0]):
        params = json.loads(str(d["params"][i]))
        prov = json.loads(str(d["provenance"][i]))
        prov["bundle"] = info["name"]
        j = int(d["spectrum_index"][i])
        sl = slice(int(off[j]), int(off[j + 1])) if j >= 0 else None
        spec = {k: None if sl is None else d[k][sl] for k in ("spectrum_q", "spectrum_power", "spectrum_multiplicity")}
        q = d["quantiles"][i].astype(np.float64)
        q.setflags(write=False)
        recs.append(EnsembleRecord(key=case_key(params), params=params, provenance=prov, levels=levels, quantiles=q,
                                   **spec, **{k: float(d[k][i]) for k in _SCAL}))
    return tuple(recs), info


def bundled_ensemble(name: str = "fig1_n1024") -> Ensemble:
    """A bundled ensemble as an :class:`~gfmd_ref.ensemble.store.Ensemble`.

    Parameters
    ----------
    name : {"fig1_n1024", "offscene_n512"}
        See :data:`BUNDLED_ENSEMBLES`. Select records with ``.group(wall)`` or
        ``.select(...)``; ``.info`` holds the command that regenerates it.
    """
    if name not in BUNDLED_ENSEMBLES:
        raise ValueError(f"name must be one of {sorted(BUNDLED_ENSEMBLES)}; got {name!r}")
    path = Path(__file__).resolve().parent.parent / "data" / f"ensemble_{name}.npz"
    if not path.exists():
        raise ValueError(f"bundled ensemble {name!r} is missing from the installation ({path})")
    recs, info = _load_bundle(str(path))
    return Ensemble(recs, source=f"bundled:{name}", info=info)
