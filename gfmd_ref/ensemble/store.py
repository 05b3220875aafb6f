"""The ensemble store: one small file per case, keyed by the case's parameters.

A store is a directory. Each finished case is one compressed ``.npz`` file
``<label>__<key>.npz``: ``key`` is the first 16 hex digits of the SHA-1 of the
canonical JSON of the case parameters (:func:`case_key`), ``label`` a readable name
(``n1024_hard_p0.004_s7``). A record holds the parameters, the provenance (convergence,
code version, FFT threads, host, command) and the reductions of the pressure field
(:func:`reduce_pressure_field`) and of the surface (:func:`shell_spectrum`); the fields
are listed in ``docs/ensembles.md``.

Every record is written by one ``os.replace`` of a temporary file in the same directory
(atomic on POSIX): concurrent writers never share a file, a killed process leaves at most
a ``*.tmp`` file that readers ignore, and two writers of the same case write the same
content under the same name, so the store stays duplicate-free without an index.
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

__all__ = [
    "STORE_LEVELS",
    "HIST_EDGES_P0",
    "EnsembleRecord",
    "Ensemble",
    "EnsembleGroup",
    "case_key",
    "case_label",
    "reduce_pressure_field",
    "shell_spectrum",
    "write_record",
    "read_record",
    "load_ensemble",
    "store_keys",
    "wall_label",
]

#: Quantile levels kept per case in a store: ``i/2048``, ``i = 0 ... 2048``. Between
#: two stored levels the empirical CDF is monotone, so a Kolmogorov distance read
#: from the quantiles is exact to one level step, 4.9e-4 (< 1e-3).
STORE_LEVELS = np.linspace(0.0, 1.0, 2049)
#: Histogram edges in units of the mean pressure ``p0`` (400 bins of 0.05 p0).
HIST_EDGES_P0 = np.linspace(0.0, 20.0, 401)
#: Exponential walls: contact means ``p > EXP_CONTACT_THRESHOLD * p0`` (as solve_contact).
EXP_CONTACT_THRESHOLD = 0.01
FORMAT_VERSION = 1


def wall_label(zeta: Optional[float]) -> str:
    """``"hard"`` or ``"zeta<z>"`` (``%g``)."""
    return "hard" if zeta is None else f"zeta{float(zeta):g}"


def _canonical(params: dict) -> str:
    def norm(v):
        if isinstance(v, dict):
            return {k: norm(v[k]) for k in sorted(v)}
        if isinstance(v, (float, np.floating)):
            return repr(float(v))
        if isinstance(v, (np.integer,)):
            return int(v)
        return v

    return json.dumps(norm(params), sort_keys=True, separators=(",", ":"))


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
    total = pw.sum()
    keep = (pw > 1e-24 * total) & (k2 > 0)
    uk2, inv = np.unique(k2[keep], return_inverse=True)
    power = np.bincount(inv, weights=pw[keep], minlength=uk2.size)
    mult = np.bincount(inv, minlength=uk2.size)
    q = 2.0 * math.pi / float(length) * np.sqrt(uk2.astype(float))
    return q, power, mult


def reduce_pressure_field(pressure: np.ndarray, *, mean_pressure: float, zeta: Optional[float],
                          levels: np.ndarray = STORE_LEVELS) -> dict:
    """Reduce one pressure field to what the store keeps (the single reduction used
    by live runs and by ingested fields alike).

    Parameters
    ----------
    pressure : array
        Local pressures [pressure units], any shape, finite and ``>= 0``.
    mean_pressure : float
        Nominal ``p0`` (sets the contact threshold and the histogram edges).
    zeta : float or None
        Wall range (``None``: hard wall, contact means ``p > 0``; else ``p > 0.01 p0``).
    levels : array
        Quantile levels in ``[0, 1]``.

    Returns
    -------
    dict
        ``levels``, ``quantiles`` (``np.quantile``, linear interpolation between
        order statistics), ``mean``, ``variance``, ``third_central``, ``sd``,
        ``skewness``, ``contact_fraction``, ``contact_threshold``, ``zero_weight``,
        ``hist_edges``, ``hist_counts`` (non-zero pressures only), ``hist_zero``,
        ``hist_overflow``, ``n_values``.
    """
    p = np.asarray(pressure, dtype=np.float64).ravel()
    if p.size == 0 or not np.all(np.isfinite(p)):
        raise ValueError("pressure must be a non-empty array of finite values")
    if np.any(p < 0):
        raise ValueError(f"pressure must be >= 0; found min {p.min()!r}")
    p0 = float(mean_pressure)
    srt = np.sort(p)
    q = np.quantile(srt, levels)
    mean = float(p.mean())
    c = p - mean
    var = float(np.mean(c * c))
    third = float(np.mean(c * c * c))
    sd = math.sqrt(var)
    thr = 0.0 if zeta is None else EXP_CONTACT_THRESHOLD * p0
    nz = srt[srt != 0.0]
    edges = HIST_EDGES_P0 * p0
    counts, _ = np.histogram(nz, bins=edges)
    return dict(
        levels=np.asarray(levels, dtype=np.float64),
        quantiles=q,
        mean=mean,
        variance=var,
        third_central=third,
        sd=sd,
        skewness=third / sd**3 if sd > 0 else 0.0,
        contact_fraction=float(np.count_nonzero(p > thr)) / p.size,
        contact_threshold=thr,
        zero_weight=float(p.size - nz.size) / p.size,
        hist_edges=edges,
        hist_counts=counts.astype(np.int64),
        hist_zero=int(p.size - nz.size),
        hist_overflow=int(nz.size - counts.sum()),
        n_values=int(p.size),
    )


@dataclass(frozen=True, eq=False)
class EnsembleRecord:
    """One case of an ensemble (read from a store or from bundled data).

    ``quantiles`` are the pressures [pressure units] at ``levels``; ``zeta`` is
    ``None`` for the hard wall, else in the unit of ``length`` (grid spacings, ``L = n``); ``contact_fraction`` uses the solver's definition;
    ``provenance`` says how the number was made. Records of bundled data have no
    histogram (``hist_counts is None``) and ``spectrum_q`` may be ``None``.
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

    # parameter shortcuts
    @property
    def seed(self) -> int:
        return int(self.params["seed"])

    @property
    def zeta(self) -> Optional[float]:
        z = self.params["zeta"]
        return None if z is None else float(z)

    @property
    def n(self) -> int:
        return int(self.params["n"])

    def zeta_in(self, unit: str = "grid") -> Optional[float]:
        """The wall range in ``"grid"`` spacings of this record's grid (as stored, ``L = n``)
        or in ``"paper"`` grid spacings of the 1024^2 Fig. 1 system (``zeta * 1024 / n``)."""
        if unit not in ("grid", "paper"):
            raise ValueError(f"unit must be 'grid' or 'paper'; got unit={unit!r}")
        z = self.zeta
        return z if z is None or unit == "grid" else z * 1024.0 / self.n

    @property
    def length(self) -> float:
        return float(self.params["length"])

    @property
    def mean_pressure(self) -> float:
        return float(self.params["mean_pressure"])

    @property
    def E_star(self) -> float:
        return float(self.params["E_star"])

    @property
    def converged(self) -> bool:
        return bool(self.provenance["converged"])

    @property
    def wall(self) -> str:
        return wall_label(self.zeta)

    @property
    def group_key(self) -> tuple:
        """``(zeta, mean_pressure, n)`` plus the surface and modulus (what makes a pool)."""
        return (self.zeta, self.mean_pressure, self.n, self.E_star, _canonical(self.params.get("surface", {})))

    def cdf(self, p) -> np.ndarray:
        """Empirical CDF ``P(pressure <= p)`` interpolated from the quantiles
        (exact at the stored quantiles to one level step)."""
        p = np.asarray(p, dtype=float)
        q = self.quantiles
        # right-continuous at ties (the delta at 0): last level with quantile <= p
        idx = np.searchsorted(q, p, side="right")
        lo = np.clip(idx - 1, 0, q.size - 1)
        hi = np.clip(idx, 0, q.size - 1)
        ql, qh = q[lo], q[hi]
        ll, lh = self.levels[lo], self.levels[hi]
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(qh > ql, (p - ql) / np.where(qh > ql, qh - ql, 1.0), 0.0)
        out = ll + np.clip(t, 0.0, 1.0) * (lh - ll)
        return np.where(p < q[0], 0.0, np.where(p >= q[-1], 1.0, out))


def _jsonable(d: dict) -> str:
    def conv(v):
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, np.generic):
            return v.item()
        return v

    return json.dumps(conv(d), sort_keys=True)


_ARRAYS = ("levels", "quantiles", "hist_edges", "hist_counts", "spectrum_q", "spectrum_power",
           "spectrum_multiplicity")
_SCALARS = ("mean", "variance", "third_central", "sd", "skewness", "contact_fraction",
            "contact_threshold", "zero_weight", "hist_zero", "hist_overflow", "n_values")


def record_path(store: os.PathLike | str, params: dict) -> Path:
    return Path(store) / f"{case_label(params)}__{case_key(params)}.npz"


def write_record(store: os.PathLike | str, params: dict, provenance: dict, reduced: dict,
                 spectrum: Optional[tuple] = None) -> Path:
    """Write one record atomically (temporary file in the store, then ``os.replace``)."""
    store = Path(store)
    store.mkdir(parents=True, exist_ok=True)
    path = record_path(store, params)
    arrays = {k: np.asarray(reduced[k]) for k in ("levels", "quantiles", "hist_edges", "hist_counts")}
    if spectrum is not None:
        arrays["spectrum_q"], arrays["spectrum_power"], arrays["spectrum_multiplicity"] = spectrum
    scalars = {k: reduced[k] for k in _SCALARS}
    tmp = store / f".{path.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, params=_jsonable(params), provenance=_jsonable(provenance),
                            scalars=_jsonable(scalars), format_version=FORMAT_VERSION, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def read_record(path: os.PathLike | str) -> EnsembleRecord:
    """Read one record file; ValueError naming the file if it is not a readable record."""
    try:
        with np.load(path, allow_pickle=False) as z:
            params = json.loads(str(z["params"]))
            prov = json.loads(str(z["provenance"]))
            scal = json.loads(str(z["scalars"]))
            arr = {k: (np.array(z[k]) if k in z.files else None) for k in _ARRAYS}
        return EnsembleRecord(key=case_key(params), params=params, provenance=prov, **arr, **scal)
    except Exception as exc:  # zip, npy, JSON or field errors of a damaged or foreign file
        raise ValueError(f"{os.fspath(path)!r} is not a readable ensemble record ({type(exc).__name__}: {exc}); "
                         "delete it (its case is recomputed by the next run) or move it out of the store") from None


def store_keys(store: os.PathLike | str) -> set:
    """Keys of the finished cases in a store (from the file names; no file is opened)."""
    store = Path(store)
    if not store.is_dir():
        return set()
    return {p.stem.rsplit("__", 1)[-1] for p in store.glob("*__*.npz")}


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def host() -> str:
    return socket.gethostname()


# ----------------------------------------------------------------------------- collections


@dataclass(frozen=True, eq=False)
class EnsembleGroup:
    """The records of one pool: one wall, load, grid (and surface, modulus).

    ``records`` are the converged ones (what reductions use), one per seed;
    ``excluded`` the non-converged ones, kept visible (``n_excluded``);
    ``superseded`` further converged records of a seed already in ``records`` (the
    same case at another ``tol``/``max_iter``: the smallest tol, then residual, wins).
    """

    zeta: Optional[float]
    mean_pressure: float
    n: int
    records: tuple
    excluded: tuple = ()
    superseded: tuple = ()

    @property
    def wall(self) -> str:
        return wall_label(self.zeta)

    @property
    def seeds(self) -> list:
        return sorted(r.seed for r in self.records)

    @property
    def n_seeds(self) -> int:
        return len(self.records)

    @property
    def n_excluded(self) -> int:
        return len(self.excluded)

    @property
    def E_star(self) -> float:
        return self.records[0].E_star if self.records else self.excluded[0].E_star

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

    ``records`` holds every record, converged or not; :meth:`groups` and
    :meth:`group` pool the converged ones per (wall, load, grid) and count the rest.
    """

    def __init__(self, records: Iterable[EnsembleRecord], *, source: str = "", info: Optional[dict] = None):
        recs = list(records)
        recs.sort(key=lambda r: (r.n, r.mean_pressure, -1.0 if r.zeta is None else r.zeta, r.seed))
        self.records = recs
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
        zs = {r.zeta for r in self.records}
        return sorted(zs, key=lambda z: -1.0 if z is None else z)

    def select(self, *, wall=..., zeta=..., mean_pressure=None, n=None, seeds=None,
               converged: Optional[bool] = None) -> list:
        """Records matching every given criterion. ``wall`` may be ``"hard"``, a
        float zeta or ``None``; ``zeta=None`` also means the hard wall."""
        if wall is not ... and zeta is not ...:
            raise ValueError("give wall or zeta, not both")
        target = ...
        if wall is not ...:
            target = _parse_wall(wall)
        elif zeta is not ...:
            target = None if zeta is None else float(zeta)
        out = []
        for r in self.records:
            if target is not ... and not _same_zeta(r.zeta, target):
                continue
            if mean_pressure is not None and not math.isclose(r.mean_pressure, mean_pressure, rel_tol=1e-12):
                continue
            if n is not None and r.n != int(n):
                continue
            if seeds is not None and r.seed not in set(seeds):
                continue
            if converged is not None and r.converged != converged:
                continue
            out.append(r)
        return out

    def groups(self) -> list:
        """One :class:`EnsembleGroup` per (wall, load, grid, surface, modulus)."""
        by: dict = {}
        for r in self.records:
            by.setdefault(r.group_key, []).append(r)
        out = []
        for k, recs in by.items():
            best: dict = {}
            extra = []
            for r in sorted((r for r in recs if r.converged), key=_rank):
                if r.seed in best:
                    extra.append(r)
                else:
                    best[r.seed] = r
            conv = tuple(best[s] for s in sorted(best))
            bad = tuple(sorted((r for r in recs if not r.converged), key=lambda r: r.seed))
            out.append(EnsembleGroup(k[0], k[1], k[2], conv, bad, tuple(extra)))
        out.sort(key=lambda g: (g.n, g.mean_pressure, -1.0 if g.zeta is None else g.zeta))
        return out

    def group(self, wall=..., *, zeta=..., mean_pressure=None, n=None, seeds=None) -> EnsembleGroup:
        """The single group of ``wall`` (``"hard"``/None or a zeta; default the hard
        wall), or equivalently of ``zeta`` (None = hard wall), as in :meth:`select`;
        ``mean_pressure`` and ``n`` are needed only when the ensemble has several."""
        if wall is ... and zeta is ...:
            wall = "hard"
        recs = self.select(wall=wall, zeta=zeta, mean_pressure=mean_pressure, n=n, seeds=seeds)
        if wall is ...:
            wall = "hard" if zeta is None else zeta
        if not recs:
            raise ValueError(f"no records for wall={wall!r}, mean_pressure={mean_pressure!r}, n={n!r}; "
                             f"walls present: {[wall_label(z) for z in self.zetas]}")
        keys = {r.group_key for r in recs}
        if len(keys) > 1:
            raise ValueError(f"wall={wall!r} matches {len(keys)} groups (loads/grids {sorted({(k[1], k[2]) for k in keys})}); "
                             "give mean_pressure= and n=")
        return Ensemble(recs).groups()[0]

    def summary_rows(self) -> list:
        """Per-group table rows (dicts): counts, contact fraction, sd, skewness
        (mean and seed-to-seed sd over converged records), non-converged count."""
        rows = []
        for g in self.groups():
            recs = g.records

            def ms(attr):
                v = np.array([getattr(r, attr) for r in recs], dtype=float)
                if v.size == 0:
                    return float("nan"), float("nan")
                return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0

            cf, cf_s = ms("contact_fraction")
            sd, sd_s = ms("sd")
            sk, sk_s = ms("skewness")
            it = [int(r.provenance.get("iterations", 0)) for r in recs]
            wt = [float(r.provenance.get("wall_time", float("nan"))) for r in recs]
            rows.append(dict(wall=g.wall, zeta=g.zeta, mean_pressure=g.mean_pressure, n=g.n,
                             seeds=g.n_seeds, not_converged=g.n_excluded,
                             contact_fraction=cf, contact_fraction_sd=cf_s, sd=sd, sd_sd=sd_s,
                             skewness=sk, skewness_sd=sk_s,
                             median_iterations=float(np.median(it)) if it else float("nan"),
                             median_wall_time=float(np.median(wt)) if wt else float("nan")))
        return rows

    def summary(self) -> str:
        """The per-group table as text (what ``gfmd-ref ensemble-summary`` prints)."""
        rows = self.summary_rows()
        lines = [f"ensemble: {self.source or '(in memory)'}: {len(self.records)} records in {len(rows)} groups; "
                 f"{self.n_not_converged} not converged (excluded from every reduction); "
                 "wall zeta in grid spacings of the record's grid (L = n)",
                 f"{'n':>5} {'p0':>8} {'wall':>10} {'seeds':>5} {'not conv':>8} "
                 f"{'contact frac (sd)':>20} {'sd/p0 (sd)':>16} {'skewness (sd)':>16} {'med it':>7} {'med s':>7}"]
        for r in rows:
            p0 = r["mean_pressure"]
            lines.append(
                f"{r['n']:>5} {p0:>8.4g} {r['wall']:>10} {r['seeds']:>5} {r['not_converged']:>8} "
                f"{r['contact_fraction']:>11.5f} ({r['contact_fraction_sd']:.5f}) "
                f"{r['sd'] / p0:>8.4f} ({r['sd_sd'] / p0:.4f}) "
                f"{r['skewness']:>8.3f} ({r['skewness_sd']:.3f}) "
                f"{r['median_iterations']:>7.0f} {r['median_wall_time']:>7.2f}")
        return "\n".join(lines)


def _rank(r: EnsembleRecord) -> tuple:
    return (float(r.params.get("tol", 1.0)), float(r.provenance.get("residual", 1.0)), r.key)


def _parse_wall(wall) -> Optional[float]:
    if wall is None:
        return None
    if isinstance(wall, str):
        w = wall.strip().lower()
        if w in ("hard", "hardwall", "hard-wall"):
            return None
        if w.startswith("zeta"):
            w = w[4:]
        try:
            return float(w)
        except ValueError:
            raise ValueError(f"wall must be 'hard' or a zeta > 0; got {wall!r}") from None
    return float(wall)


def _same_zeta(a: Optional[float], b: Optional[float]) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return math.isclose(a, b, rel_tol=1e-9)


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
    info = {}
    man = path / "ensemble.json"
    if man.exists():
        info = json.loads(man.read_text())
    return Ensemble((read_record(f) for f in files), source=str(path), info=info)
