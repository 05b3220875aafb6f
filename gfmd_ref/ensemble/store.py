"""The ensemble store: a directory with one compressed ``.npz`` per finished case,
``<label>__<key>.npz`` (``key``: 16 hex digits of the SHA-1 of the case parameters' canonical
JSON, :func:`case_key`; ``label``: e.g. ``n1024_hard_p0.004_s7``), holding the parameters, the
provenance and the reductions of the pressure field and the surface (fields listed in
``docs/ensembles.md``). Each record is written by one ``os.replace`` of a temporary file in
the same directory: a killed process leaves at most a ``*.tmp`` file that readers ignore, and
two writers of the same case write the same file, so the store needs no index.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import socket
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Optional

import numpy as np

from ..histogram import PressureHistogram
from ..solvers import EXP_CONTACT_THRESHOLD

host = socket.gethostname

__all__ = ["STORE_LEVELS", "HIST_EDGES_P0", "EnsembleRecord", "Ensemble", "EnsembleGroup", "case_key", "case_label",
           "reduce_pressure_field", "shell_spectrum", "write_record", "read_record", "load_ensemble", "store_keys",
           "wall_label"]

#: Quantile levels kept per case in a store: ``i/2048``, ``i = 0 ... 2048``. Between
#: two stored levels the empirical CDF is monotone, so a Kolmogorov distance read
#: from the quantiles is exact to one level step, 4.9e-4 (< 1e-3).
STORE_LEVELS = np.linspace(0.0, 1.0, 2049)
#: Histogram edges in units of the mean pressure ``p0`` (400 bins of 0.05 p0).
HIST_EDGES_P0 = np.linspace(0.0, 20.0, 401)
FORMAT_VERSION = 1


def wall_label(zeta: Optional[float]) -> str:
    """``"hard"`` or ``"zeta<z>"`` (``%g``)."""
    return "hard" if zeta is None else f"zeta{float(zeta):g}"


def parse_wall(wall) -> Optional[float]:
    """``"hard"`` (or ``None``) -> ``None``; ``"zeta0.5"``, ``"0.5"`` or a number -> a float."""
    if wall is None:
        return None
    if isinstance(wall, str):
        w = wall.strip().lower()
        if w in ("hard", "hardwall", "hard-wall"):
            return None
        try:
            return float(w[4:] if w.startswith("zeta") else w)
        except ValueError:
            raise ValueError(f"wall must be 'hard' or a zeta > 0; got {wall!r}") from None
    return float(wall)


def _jsonable(d: dict) -> str:
    def conv(v):
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        return v.item() if isinstance(v, np.generic) else v

    return json.dumps(conv(d), sort_keys=True)


def _canonical(params: dict) -> str:
    """Sorted compact JSON with every float written as its repr (the key's text)."""
    def norm(v):
        return {k: norm(x) for k, x in v.items()} if isinstance(v, dict) else repr(v) if isinstance(v, float) else v

    return json.dumps(norm(json.loads(_jsonable(params))), sort_keys=True, separators=(",", ":"))


def case_key(params: dict) -> str:
    """16 hex digits identifying a case by its parameters (floats by their repr)."""
    return hashlib.sha1(_canonical(params).encode()).hexdigest()[:16]


def case_label(params: dict) -> str:
    """Readable file-name stem, e.g. ``n1024_zeta0.25_p0.004_s7``."""
    return f"n{params['n']}_{wall_label(params['zeta'])}_p{params['mean_pressure']:g}_s{params['seed']}"


def shell_spectrum(heights: np.ndarray, length: float):
    """Exact shell spectrum of a periodic ``(n, n)`` height map.

    ``h~(q) = FFT(h)/n^2``; modes of equal ``m^2 + k^2`` are merged. Returns
    ``(q, power, multiplicity)`` with ``q = 2 pi sqrt(m^2 + k^2)/L`` [rad/length],
    ``power = sum |h~|^2`` over the shell [length^2] (``sum(power) = var(h)``), empty
    shells (relative power < 1e-24) dropped: the same definition as
    ``diffusion_pr.spectra.DiscreteSpectrum.from_heights``.
    """
    h = np.asarray(heights, dtype=np.float64)
    n = h.shape[0]
    ht = np.fft.fft2(h) / (n * n)
    pw = (ht.real**2 + ht.imag**2).ravel()
    k = np.fft.fftfreq(n, d=1.0 / n).astype(np.int64)
    k2 = (k[:, None] ** 2 + k[None, :] ** 2).ravel()
    pw[0] = 0.0
    keep = (pw > 1e-24 * pw.sum()) & (k2 > 0)
    uk2, inv = np.unique(k2[keep], return_inverse=True)
    power = np.bincount(inv, weights=pw[keep], minlength=uk2.size)
    mult = np.bincount(inv, minlength=uk2.size)
    return 2.0 * math.pi / float(length) * np.sqrt(uk2.astype(float)), power, mult


def reduce_pressure_field(pressure: np.ndarray, *, mean_pressure: float, zeta: Optional[float]) -> dict:
    """Reduce one pressure field to what the store keeps (the one reduction of live runs
    and ingested fields, :meth:`~gfmd_ref.PressureHistogram.from_pressures`).

    Parameters
    ----------
    pressure : array
        Local pressures [pressure units], any shape, finite and ``>= 0``.
    mean_pressure : float
        Nominal ``p0`` (sets the contact threshold and the histogram edges).
    zeta : float or None
        Wall range (``None``: hard wall, contact means ``p > 0``; else ``p > 0.01 p0``).

    Returns
    -------
    dict
        ``levels`` (:data:`STORE_LEVELS`), ``quantiles`` (``np.quantile``, linear
        interpolation between order statistics), ``mean``, ``variance``,
        ``third_central``, ``sd``, ``skewness``, ``contact_fraction``,
        ``contact_threshold``, ``zero_weight``, ``hist_edges``, ``hist_counts`` (non-zero
        pressures only), ``hist_zero``, ``hist_overflow``, ``n_values``.
    """
    p0 = float(mean_pressure)
    thr = 0.0 if zeta is None else EXP_CONTACT_THRESHOLD * p0
    hist = PressureHistogram.from_pressures(pressure, bins=HIST_EDGES_P0 * p0, n_quantiles=STORE_LEVELS.size,
                                            contact_threshold=thr)
    m = hist.moments
    sd = math.sqrt(m["variance"])
    return dict(levels=hist.quantile_levels, quantiles=hist.quantiles, mean=m["mean"], variance=m["variance"],
                third_central=m["third_central"], sd=sd, skewness=m["third_central"] / sd**3 if sd > 0 else 0.0,
                contact_fraction=m["contact_fraction"], contact_threshold=thr, zero_weight=hist.zero_weight,
                hist_edges=hist.edges, hist_counts=hist.counts.astype(np.int64),
                hist_zero=int(hist.n_total - hist.counts.sum() - hist.n_outside), hist_overflow=hist.n_outside,
                n_values=hist.n_total)


@dataclass(frozen=True, eq=False)
class EnsembleRecord:
    """One case of an ensemble (read from a store or from bundled data).

    ``quantiles`` are the pressures [pressure units] at ``levels``; ``zeta`` is ``None``
    for the hard wall, else in the unit of ``length`` (grid spacings, ``L = n``);
    ``contact_fraction`` uses the solver's definition; ``provenance`` says how the number
    was made. Records of bundled data have no histogram (``hist_counts is None``) and
    ``spectrum_q`` may be ``None``.
    """

    key: str
    params: dict
    provenance: dict
    levels: np.ndarray
    quantiles: np.ndarray
    mean: float
    variance: float
    third_central: float
    sd: float
    skewness: float
    contact_fraction: float
    contact_threshold: float
    zero_weight: float
    hist_edges: Optional[np.ndarray] = None
    hist_counts: Optional[np.ndarray] = None
    hist_zero: int = 0
    hist_overflow: int = 0
    n_values: int = 0
    spectrum_q: Optional[np.ndarray] = None
    spectrum_power: Optional[np.ndarray] = None
    spectrum_multiplicity: Optional[np.ndarray] = None

    seed = property(lambda self: int(self.params["seed"]))
    n = property(lambda self: int(self.params["n"]))
    length = property(lambda self: float(self.params["length"]))
    mean_pressure = property(lambda self: float(self.params["mean_pressure"]))
    E_star = property(lambda self: float(self.params["E_star"]))
    converged = property(lambda self: bool(self.provenance["converged"]))
    zeta = property(lambda self: parse_wall(self.params["zeta"]))
    wall = property(lambda self: wall_label(self.zeta))

    def zeta_in(self, unit: str = "grid") -> Optional[float]:
        """The wall range in ``"grid"`` spacings of this record's grid (as stored, ``L = n``)
        or in ``"paper"`` grid spacings of the 1024^2 Fig. 1 system (``zeta * 1024 / n``)."""
        if unit not in ("grid", "paper"):
            raise ValueError(f"unit must be 'grid' or 'paper'; got unit={unit!r}")
        z = self.zeta
        return z if z is None or unit == "grid" else z * 1024.0 / self.n

    @property
    def group_key(self) -> tuple:
        """``(zeta, mean_pressure, n)`` plus the modulus and surface (what makes a pool)."""
        return (self.zeta, self.mean_pressure, self.n, self.E_star, _canonical(self.params.get("surface", {})))

    def cdf(self, p) -> np.ndarray:
        """Empirical CDF ``P(pressure <= p)``, linear between the quantiles (exact at the
        stored quantiles to one level step; at tied quantiles, such as the hard wall's zeros,
        the last level: right-continuous)."""
        return np.interp(np.asarray(p, dtype=float), self.quantiles, self.levels, left=0.0, right=1.0)


_ARRAYS = ("levels", "quantiles", "hist_edges", "hist_counts", "spectrum_q", "spectrum_power",
           "spectrum_multiplicity")
_SCALARS = ("mean", "variance", "third_central", "sd", "skewness", "contact_fraction",
            "contact_threshold", "zero_weight", "hist_zero", "hist_overflow", "n_values")


def write_record(store: os.PathLike | str, params: dict, provenance: dict, reduced: dict,
                 spectrum: Optional[tuple] = None) -> Path:
    """Write one record atomically (temporary file in the store, then ``os.replace``)."""
    store = Path(store)
    store.mkdir(parents=True, exist_ok=True)
    path = store / f"{case_label(params)}__{case_key(params)}.npz"
    arrays = {k: np.asarray(reduced[k]) for k in _ARRAYS[:4]}
    if spectrum is not None:
        arrays.update(zip(_ARRAYS[4:], spectrum))
    tmp = store / f".{path.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, params=_jsonable(params), provenance=_jsonable(provenance),
                            scalars=_jsonable({k: reduced[k] for k in _SCALARS}), format_version=FORMAT_VERSION,
                            **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def read_record(path: os.PathLike | str) -> EnsembleRecord:
    """Read one record file; ValueError naming the file if it is not a readable record."""
    try:
        with np.load(path, allow_pickle=False) as z:
            params = json.loads(str(z["params"]))
            arr = {k: (np.array(z[k]) if k in z.files else None) for k in _ARRAYS}
            return EnsembleRecord(key=case_key(params), params=params, provenance=json.loads(str(z["provenance"])),
                                  **arr, **json.loads(str(z["scalars"])))
    except Exception as exc:  # zip, npy, JSON or field errors of a damaged or foreign file
        raise ValueError(f"{os.fspath(path)!r} is not a readable ensemble record ({type(exc).__name__}: {exc}); "
                         "delete it (its case is recomputed by the next run) or move it out of the store") from None


def store_keys(store: os.PathLike | str) -> set:
    """Keys of the finished cases in a store (from the file names; no file is opened)."""
    return {p.stem.rsplit("__", 1)[-1] for p in Path(store).glob("*__*.npz")} if Path(store).is_dir() else set()


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _wall_order(z: Optional[float]) -> float:
    return -1.0 if z is None else z


@dataclass(frozen=True, eq=False)
class EnsembleGroup:
    """The records of one pool: one wall, load, grid (and surface, modulus).

    ``records`` are the converged ones (what reductions use), one per seed; ``excluded``
    the non-converged ones, kept visible (``n_excluded``); ``superseded`` further
    converged records of a seed already in ``records`` (the same case at another
    ``tol``/``max_iter``: the smallest tol, then residual, wins).
    """

    zeta: Optional[float]
    mean_pressure: float
    n: int
    records: tuple
    excluded: tuple = ()
    superseded: tuple = ()

    wall = property(lambda self: wall_label(self.zeta))
    seeds = property(lambda self: sorted(r.seed for r in self.records))
    n_seeds = property(lambda self: len(self.records))
    n_excluded = property(lambda self: len(self.excluded))
    E_star = property(lambda self: (self.records or self.excluded)[0].E_star)

    def cdf(self, p) -> np.ndarray:
        """Pooled CDF: the mean of the per-seed empirical CDFs (equal area per seed)."""
        if not self.records:
            raise ValueError(f"group {self.wall}, p0={self.mean_pressure}, n={self.n} has no converged record")
        return np.mean([r.cdf(p) for r in self.records], axis=0)

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self):
        return iter(self.records)


class Ensemble:
    """A set of records (from :func:`load_ensemble` or :func:`bundled_ensemble`).

    ``records`` holds every record, converged or not; :meth:`groups` and :meth:`group`
    pool the converged ones per (wall, load, grid) and count the rest.
    """

    def __init__(self, records: Iterable[EnsembleRecord], *, source: str = "", info: Optional[dict] = None):
        self.records = sorted(records, key=lambda r: (r.n, r.mean_pressure, _wall_order(r.zeta), r.seed))
        self.source = source
        self.info = dict(info or {})

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[EnsembleRecord]:
        return iter(self.records)

    def __repr__(self) -> str:
        return (f"Ensemble({len(self.records)} records, {len(self.groups())} groups, "
                f"{self.n_not_converged} not converged, source={self.source!r})")

    @property
    def n_not_converged(self) -> int:
        return sum(not r.converged for r in self.records)

    @property
    def zetas(self) -> list:
        """Walls present (``None`` = hard wall first, then increasing zeta)."""
        return sorted({r.zeta for r in self.records}, key=_wall_order)

    def select(self, *, wall=..., zeta=..., mean_pressure=None, n=None, seeds=None,
               converged: Optional[bool] = None) -> list:
        """Records matching every given criterion. ``wall`` may be ``"hard"``, a float zeta
        or ``None``; ``zeta=None`` also means the hard wall."""
        if wall is not ... and zeta is not ...:
            raise ValueError("give wall or zeta, not both")
        target = ... if wall is ... and zeta is ... else parse_wall(wall if zeta is ... else zeta)
        return [r for r in self.records
                if (target is ... or (r.zeta is None and target is None)
                    or (None not in (r.zeta, target) and math.isclose(r.zeta, target, rel_tol=1e-9)))
                and (mean_pressure is None or math.isclose(r.mean_pressure, mean_pressure, rel_tol=1e-12))
                and (n is None or r.n == int(n)) and (seeds is None or r.seed in set(seeds))
                and (converged is None or r.converged == converged)]

    def groups(self) -> list:
        """One :class:`EnsembleGroup` per (wall, load, grid, surface, modulus)."""
        by: dict = {}
        for r in self.records:
            by.setdefault(r.group_key, []).append(r)
        out = []
        for k, recs in by.items():
            best: dict = {}
            extra = []
            rank = (lambda r: (float(r.params.get("tol", 1.0)), float(r.provenance.get("residual", 1.0)), r.key))
            for r in sorted((r for r in recs if r.converged), key=rank):
                if best.setdefault(r.seed, r) is not r:
                    extra.append(r)
            bad = tuple(sorted((r for r in recs if not r.converged), key=lambda r: r.seed))
            out.append(EnsembleGroup(k[0], k[1], k[2], tuple(best[s] for s in sorted(best)), bad, tuple(extra)))
        return sorted(out, key=lambda g: (g.n, g.mean_pressure, _wall_order(g.zeta)))

    def group(self, wall=..., *, zeta=..., mean_pressure=None, n=None, seeds=None) -> EnsembleGroup:
        """The single group of ``wall`` (``"hard"``/None or a zeta; default the hard wall),
        or equivalently of ``zeta`` (None = hard wall), as in :meth:`select`;
        ``mean_pressure`` and ``n`` are needed only when the ensemble has several."""
        if wall is ... and zeta is ...:
            wall = "hard"
        recs = self.select(wall=wall, zeta=zeta, mean_pressure=mean_pressure, n=n, seeds=seeds)
        wall = wall if zeta is ... else ("hard" if zeta is None else zeta)
        if not recs:
            raise ValueError(f"no records for wall={wall!r}, mean_pressure={mean_pressure!r}, n={n!r}; "
                             f"walls present: {[wall_label(z) for z in self.zetas]}")
        keys = {r.group_key for r in recs}
        if len(keys) > 1:
            raise ValueError(f"wall={wall!r} matches {len(keys)} groups (loads/grids "
                             f"{sorted({(k[1], k[2]) for k in keys})}); give mean_pressure= and n=")
        return Ensemble(recs).groups()[0]

    def summary(self) -> str:
        """Per-group table (what ``gfmd-ref ensemble-summary`` prints): seeds, non-converged
        count, contact fraction, sd/p0 and skewness (mean and seed-to-seed sd over the
        converged records), median iterations and wall time."""
        groups = self.groups()
        lines = [f"ensemble: {self.source or '(in memory)'}: {len(self.records)} records in {len(groups)} groups; "
                 f"{self.n_not_converged} not converged (excluded from every reduction); "
                 "wall zeta in grid spacings of the record's grid (L = n)",
                 f"{'n':>5} {'p0':>8} {'wall':>10} {'seeds':>5} {'not conv':>8} "
                 f"{'contact frac (sd)':>20} {'sd/p0 (sd)':>16} {'skewness (sd)':>16} {'med it':>7} {'med s':>7}"]
        for g in groups:
            def ms(attr, scale=1.0):
                v = np.array([getattr(r, attr) for r in g], dtype=float) / scale
                return (float("nan"),) * 2 if v.size == 0 else (v.mean(), v.std(ddof=1) if v.size > 1 else 0.0)

            def median(key):
                return float(np.median([float(r.provenance.get(key, float("nan"))) for r in g])) if g.records \
                    else float("nan")

            cf, sd, sk = ms("contact_fraction"), ms("sd", g.mean_pressure), ms("skewness")
            lines.append(f"{g.n:>5} {g.mean_pressure:>8.4g} {g.wall:>10} {g.n_seeds:>5} {g.n_excluded:>8} "
                         f"{cf[0]:>11.5f} ({cf[1]:.5f}) {sd[0]:>8.4f} ({sd[1]:.4f}) {sk[0]:>8.3f} ({sk[1]:.3f}) "
                         f"{median('iterations'):>7.0f} {median('wall_time'):>7.2f}")
        return "\n".join(lines)


def load_ensemble(store: os.PathLike | str) -> Ensemble:
    """Read every record of a store directory (``*.tmp`` leftovers are ignored).

    Raises ``ValueError`` if the directory does not exist or holds no record.
    """
    path = Path(store)
    if not path.is_dir():
        raise ValueError(f"store must be an existing directory; got {str(store)!r}")
    files = sorted(path.glob("*__*.npz"))
    if not files:
        raise ValueError(f"store {str(store)!r} holds no ensemble record (*__<key>.npz)")
    man = path / "ensemble.json"
    return Ensemble((read_record(f) for f in files), source=str(path),
                    info=json.loads(man.read_text()) if man.exists() else {})
