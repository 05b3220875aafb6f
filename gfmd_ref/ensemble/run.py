"""GFMD ensembles on Dask: seeds x walls x loads x grid sizes, resumable (docs/ensembles.md).

Each case is one :func:`~gfmd_ref.solve_contact` on a self-affine surface (default: the
paper's Fig. 1 surface), reduced and written as one record of a store directory by the
worker that solved it, on an existing Dask cluster, a local cluster (one single-threaded
worker per core) or, with ``serial=True``, in this process (Dask is the optional
``diffusion-pr[ensemble]``). Parameters are checked before anything is scheduled.
"""
from __future__ import annotations

import functools
import importlib
import json
import math
import numbers
import os
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from .._validation import check_int, check_positive, check_real, check_tol, check_writable_dir
from ..scene import FIG1, band_surface, zeta_on_grid
from ..interactions import ExponentialRepulsion, HardWall
from ..solvers import METHODS, ConvergenceWarning, solve_contact
from .store import (Ensemble, case_key, case_label, host, load_ensemble, now_iso, parse_wall, reduce_pressure_field,
                    shell_spectrum, store_keys, wall_label, write_record)

__all__ = ["EnsembleSurface", "FIG1_SURFACE", "EnsembleRun", "build_cases", "parse_seeds", "parse_walls",
           "case_surface", "solve_case", "run_ensemble", "ingest_fields", "code_version"]


@dataclass(frozen=True)
class EnsembleSurface:
    """Surface family of an ensemble: Gaussian self-affine, ``L = n`` grid units.

    Parameters
    ----------
    hurst : float
        Hurst exponent ``H`` in ``[0, 1]``.
    rms_slope : float
        Spectral rms slope (> 0, dimensionless).
    n_waves : int
        ``q_max / q_min`` with ``q_min = 2 pi / L``: the shortest wavelength is
        ``L / n_waves``; needs ``2 n_waves <= n`` (below the Nyquist wavenumber).

    Notes
    -----
    The Fig. 1 family (:data:`FIG1_SURFACE`) generates exactly
    :func:`~gfmd_ref.fig1_surface`. The same family at several ``n`` is the same
    physical system (all lengths in units of ``L``) at a finer discretisation.
    """

    hurst: float = FIG1["hurst"]
    rms_slope: float = FIG1["rms_slope"]
    n_waves: int = FIG1["n_waves"]

    def __post_init__(self):
        object.__setattr__(self, "hurst", check_real("hurst", self.hurst, low=0.0, high=1.0))
        object.__setattr__(self, "rms_slope", check_positive("rms_slope", self.rms_slope))
        object.__setattr__(self, "n_waves", check_int("n_waves", self.n_waves))

    def as_dict(self) -> dict:
        return dict(kind="self_affine", hurst=self.hurst, rms_slope=self.rms_slope, n_waves=self.n_waves)


#: The paper's Fig. 1 surface family (H = 0.3, rms slope 0.031, wavelengths L ... L/32).
FIG1_SURFACE = EnsembleSurface()


def case_surface(params: dict) -> np.ndarray:
    """Heights of a case (deterministic in its parameters)."""
    s = params["surface"]
    return band_surface(int(params["n"]), float(params["length"]), float(s["hurst"]), float(s["rms_slope"]),
                        int(s["n_waves"]), int(params["seed"]))


@functools.lru_cache(maxsize=None)
def _code_version() -> tuple:
    try:
        from importlib.metadata import version

        ver = version("diffusion-pr")
    except Exception:  # pragma: no cover - not installed
        ver = "unknown"
    here = str(Path(__file__).resolve().parent)

    def git(*args):
        out = subprocess.run(["git", "-C", here, *args], capture_output=True, text=True, timeout=5)
        return out.stdout.strip() if out.returncode == 0 else None

    try:
        rev = git("rev-parse", "--short=12", "HEAD")
        return ver, rev + ("+dirty" if git("status", "--porcelain", "--", ".") else "") if rev else "unknown"
    except Exception:  # pragma: no cover - no git
        return ver, "unknown"


def code_version() -> dict:
    """``{"package", "version", "git"}`` of the code making a record (git revision of
    the gfmd_ref sources with ``+dirty`` if they have uncommitted changes)."""
    ver, rev = _code_version()
    return dict(package="diffusion-pr", version=ver, git=rev)


def parse_seeds(spec) -> list:
    """``"1-16"``, ``"1,3,5-7"``, an int or a sequence of ints (>= 0) -> sorted unique list."""
    if isinstance(spec, numbers.Integral) and not isinstance(spec, bool):
        spec = [int(spec)]
    if isinstance(spec, str):
        out = []
        for part in filter(None, (p.strip() for p in spec.split(","))):
            a, _, b = part.partition("-")
            try:
                lo, hi = int(a), int(b or a)
            except ValueError:
                lo, hi = 0, -1
            if hi < lo:
                raise ValueError(f"seeds must look like '1-16' or '1,3,5-7' (integers >= 0); got {spec!r}")
            out.extend(range(lo, hi + 1))
        spec = out
    seeds = sorted({check_int("seeds", s, minimum=0) for s in spec})
    if not seeds:
        raise ValueError(f"seeds must name at least one seed; got {spec!r}")
    return seeds


def parse_walls(spec) -> list:
    """``"hard,4,0.25"`` or a sequence of ``"hard"``/None/zeta -> list of ``None``/float."""
    if isinstance(spec, str):
        spec = [w for w in spec.split(",") if w.strip()]
    if spec is None or isinstance(spec, numbers.Number):
        spec = [spec]
    out = []
    for w in spec:
        z = parse_wall(w)
        if z is not None and not (math.isfinite(z) and z > 0):
            raise ValueError(f"walls: zeta must be a finite number > 0 (or 'hard'); got {w!r}")
        if z not in out:
            out.append(z)
    if not out:
        raise ValueError(f"walls must name at least one wall; got {spec!r}")
    return out


def _floats(name, values) -> list:
    values = [values] if isinstance(values, (numbers.Number, str)) else list(values)
    try:
        out = [check_positive(name, float(v)) for v in values]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be finite numbers > 0; got {values!r}") from None
    if not out:
        raise ValueError(f"{name} must not be empty")
    return out


def build_cases(*, n=1024, seeds=(1,), walls=("hard",), mean_pressures=None, surface: Optional[EnsembleSurface] = None,
                E_star: Optional[float] = None, tol: float = 1e-6, method: str = "auto",
                max_iter: Optional[int] = None, length_unit: str = "grid") -> list:
    """The case grid (list of parameter dicts), every parameter checked.

    Lengths: a case's cell is ``L = n`` grid spacings and its ``zeta`` is in that unit.
    ``length_unit="paper"`` reads the zetas of ``walls`` in grid spacings of the paper's
    1024^2 system (``L = 1024``) and converts them to ``zeta * n / 1024`` on each grid.

    ``max_iter`` (default: the solver's) enters the parameters, hence the key, only when
    given: rerunning non-converged cases with a larger ``max_iter`` makes new records
    (both are kept; reductions use the converged ones).

    Order: grid size, load, then seeds outer and walls inner. Raises ``ValueError``
    naming the parameter, value and allowed range.
    """
    surface = FIG1_SURFACE if surface is None else surface
    if not isinstance(surface, EnsembleSurface):
        raise ValueError(f"surface must be an EnsembleSurface; got {type(surface).__name__}")
    grid = []
    for v in [n] if isinstance(n, (numbers.Integral, str)) else list(n):
        v = int(v) if isinstance(v, str) and v.strip().isdigit() else v
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 2:
            raise ValueError(f"n must be integers >= 2; got {v!r}")
        if 2 * surface.n_waves > v:
            raise ValueError(f"n must be >= 2 n_waves = {2 * surface.n_waves} (q_max below Nyquist); got n={v}")
        grid.append(int(v))
    seeds = parse_seeds(seeds)
    walls = parse_walls(walls)
    loads = _floats("mean_pressures", FIG1["mean_pressure"] if mean_pressures is None else mean_pressures)
    E = _floats("E_star", FIG1["E_star"] if E_star is None else E_star)[0]
    tol = check_tol(tol)
    if length_unit not in ("grid", "paper"):
        raise ValueError(f"length_unit must be 'grid' or 'paper'; got length_unit={length_unit!r}")
    allowed = ("auto", "ccg", "pk", "newton", "fire")
    if method not in allowed:
        raise ValueError(f"method must be one of {allowed}; got {method!r}")
    for z in walls:
        if method != "auto" and method not in METHODS["HardWall" if z is None else "ExponentialRepulsion"]:
            raise ValueError(f"method={method!r} does not apply to wall {wall_label(z)} "
                             "(ccg, pk: hard wall only, newton: exponential walls only; use 'auto')")
    extra = {} if max_iter is None else {"max_iter": check_int("max_iter", max_iter)}
    return [dict(n=nn, length=float(nn), seed=s, mean_pressure=p0, E_star=E, surface=surface.as_dict(), tol=tol,
                 method=method, zeta=zeta_on_grid(z, nn) if z is not None and length_unit == "paper" else z, **extra)
            for nn in grid for p0 in loads for s in seeds for z in walls]


def _store_case(store, params: dict, pressure: np.ndarray, heights: np.ndarray, provenance: dict) -> Path:
    """Reduce a case's pressure field and its surface and write the record."""
    red = reduce_pressure_field(pressure, mean_pressure=params["mean_pressure"], zeta=params["zeta"])
    return write_record(store, params, provenance, red, shell_spectrum(heights, params["length"]))


def solve_case(params: dict, store: str, provenance: Optional[dict] = None, threads: int = 1) -> dict:
    """Solve, reduce and store one case with ``threads`` FFT threads (runs on a worker).
    Returns its provenance and ``path``."""
    h = case_surface(params)
    inter = HardWall() if params["zeta"] is None else ExponentialRepulsion(params["zeta"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # recorded in the record instead
        res = solve_contact(h, length=params["length"], E_star=params["E_star"],
                            mean_pressure=params["mean_pressure"], interaction=inter, tol=params["tol"],
                            method=params["method"], max_iter=params.get("max_iter"), threads=threads)
    prov = dict(provenance or {})
    prov.update(source="live", converged=bool(res.converged), residual=float(res.residual),
                iterations=int(res.iterations), wall_time=res.wall_time, method=res.method, message=res.message,
                fft_threads=threads, host=host(), pid=os.getpid(), created=now_iso())
    prov.setdefault("code", code_version())
    return dict(prov, path=str(_store_case(store, params, res.pressure, h, prov)))


@dataclass(frozen=True)
class EnsembleRun:
    """What :func:`run_ensemble` (or :func:`ingest_fields`) did.

    ``n_cases`` in the grid, ``n_skipped`` already in the store, ``n_computed`` now,
    ``n_not_converged`` among those computed now (kept in the store, excluded from
    reductions), ``failed`` maps case labels to error messages (not stored; a rerun
    retries them), ``wall_time`` [s].
    """

    store: str
    n_cases: int
    n_skipped: int
    n_computed: int
    n_not_converged: int
    failed: dict
    wall_time: float
    scheduler: str
    message: str = ""

    @property
    def success(self) -> bool:
        return not self.failed and self.n_skipped + self.n_computed == self.n_cases

    def load(self) -> Ensemble:
        return load_ensemble(self.store)


class _Tally:
    """The cases of one run as they finish: counts, failures, a tqdm bar on stderr, the report."""

    def __init__(self, what: str, store: Path, n_cases: int, todo: int, entry: dict, progress: bool, verbose: bool,
                 stream, unit: str, **bar):
        self.what, self.store, self.n_cases, self.skipped, self.verbose = what, store, n_cases, n_cases - todo, verbose
        self.out = sys.stdout if stream is None else stream
        self.t0, self.failed, self.computed, self.not_conv, self.bar = time.perf_counter(), {}, 0, 0, None
        if verbose:
            print(f"{what}: {n_cases} {unit}s; {self.skipped} already in {store}, {todo} to run", file=self.out,
                  flush=True)
        store.mkdir(parents=True, exist_ok=True)
        if todo:  # the run's entry in the store's manifest
            man = store / "ensemble.json"
            info = json.loads(man.read_text()) if man.exists() else {"format": "gfmd_ref ensemble store",
                                                                     "version": 1, "runs": []}
            info["runs"].append(dict(entry, n_cases=n_cases, n_skipped=self.skipped, host=host()))
            tmp = store / f".ensemble.json.{os.getpid()}.tmp"
            tmp.write_text(json.dumps(info, indent=1, sort_keys=True))
            os.replace(tmp, man)
            if progress:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=todo, file=sys.stderr, unit=unit, **bar)

    def add(self, label: str, get) -> None:
        """Count the case ``label`` whose summary (a dict with ``converged``) ``get()`` returns."""
        try:
            summary = get()
        except Exception as exc:  # e.g. KilledWorker; reported, not stored; a rerun retries
            self.failed[label] = f"{type(exc).__name__}: {exc}"
        else:
            self.computed += 1
            self.not_conv += not summary["converged"]
        if self.bar is not None:
            self.bar.set_postfix(not_converged=self.not_conv, refresh=False)
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def finish(self, sched: str) -> EnsembleRun:
        t = time.perf_counter() - self.t0
        msg = (f"{self.what}: {self.computed} computed now ({self.not_conv} not converged: kept in the store, excluded "
               f"from reductions), {self.skipped} skipped, {len(self.failed)} failed; "
               f"{self.n_cases - self.skipped - self.computed} of {self.n_cases} remain; {t:.1f} s, {sched}")
        if self.verbose:
            print(msg, file=self.out, flush=True)
            for k, v in self.failed.items():
                print(f"  failed {k}: {v}", file=self.out)
        return EnsembleRun(str(self.store), self.n_cases, self.skipped, self.computed, self.not_conv, self.failed,
                           t, sched, msg)


def _local_cluster(workers: Optional[int], threads: int):
    import dask
    from dask.distributed import Client, LocalCluster

    ncpu = os.cpu_count() or 1
    workers = max(1, ncpu // threads) if workers is None else int(workers)
    # Dask's nanny sets OMP/MKL/OPENBLAS_NUM_THREADS=1; BLAS threading changes np.vdot's round-off,
    # so workers get this process's setting and give bit-identical records.
    pre = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        pre[k] = os.environ.get(k, str(ncpu))
    with dask.config.set({"distributed.nanny.pre-spawn-environ": pre}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=40)
    return Client(cluster), cluster, f"local cluster: {workers} worker(s) x 1 case, {threads} FFT thread(s) each"


def _probe_scheduler(address: str, timeout: float = 2.0) -> None:
    """ValueError naming ``address`` unless a TCP connection to it opens within ``timeout`` s
    (other transports, tls:// or inproc://, and malformed addresses are left to Dask)."""
    import socket
    from urllib.parse import urlsplit

    url = urlsplit(address if "://" in address else "tcp://" + address)
    try:
        if url.scheme == "tcp" and url.hostname and url.port is not None:
            socket.create_connection((url.hostname, url.port), timeout=timeout).close()
    except ValueError:  # a port out of range
        return
    except OSError as exc:
        raise ValueError(f"scheduler={address!r}: no Dask scheduler accepts connections there "
                         f"({exc.strerror or exc}); start one (dask scheduler) or omit --scheduler") from None


def run_ensemble(store, *, n=1024, seeds="1-4", walls=("hard",), length_unit: str = "grid", mean_pressures=None,
                 surface: Optional[EnsembleSurface] = None, E_star: Optional[float] = None, tol: float = 1e-6,
                 method: str = "auto", max_iter: Optional[int] = None, workers: Optional[int] = None,
                 threads_per_worker: Optional[int] = None,
                 scheduler: Optional[str] = None, client=None, serial: bool = False, progress: bool = True,
                 command: Optional[str] = None, verbose: bool = True, stream=None) -> EnsembleRun:
    """Run (or resume) an ensemble of GFMD cases into a store directory.

    Parameters
    ----------
    store : path
        Store directory (created if missing). Cases already in it are skipped.
    n : int or sequence of int
        Grid sizes (``L = n`` grid units).
    seeds : str, int or sequence
        Surface seeds, e.g. ``"1-64"``.
    walls : str or sequence
        ``"hard"`` and/or exponential-wall ranges ``zeta`` in the unit of ``length_unit``,
        e.g. ``"hard,4,0.25"``.
    length_unit : {"grid", "paper"}
        ``"grid"`` (default): grid spacings of each solved grid (``L = n``); ``"paper"``: grid
        spacings of the paper's 1024^2 system, stored as ``zeta * n / 1024`` (records keep
        ``zeta`` in units of their ``L = n``; :meth:`EnsembleRecord.zeta_in`).
    mean_pressures : float or sequence, optional
        Loads ``p0`` [the unit of ``E_star``] (default the paper's 0.004).
    surface : EnsembleSurface, optional
        Surface family (default Fig. 1: H = 0.3, rms slope 0.031, 32 wavelengths).
    E_star : float, optional
        Contact modulus (default 8/3).
    tol, method, max_iter
        Passed to :func:`~gfmd_ref.solve_contact` (default tol 1e-6).
    workers, threads_per_worker : int, optional
        Local cluster size (default: one single-threaded worker per core).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); one that does not
        accept a connection within 2 s is a ValueError before anything is computed.
    client : dask.distributed.Client, optional
        An existing client (takes precedence over ``scheduler``).
    serial : bool
        No cluster: solve the cases one after the other in this process.
    progress : bool
        tqdm bar of finished cases (mean rate over the run for the ETA).
    command : str, optional
        The command recorded in every record's provenance (default: this call).

    Returns
    -------
    EnsembleRun

    Raises
    ------
    ValueError
        Bad parameters, an unwritable ``store`` or an unreachable ``scheduler``, before
        any case is computed.
    """
    cases = build_cases(n=n, seeds=seeds, walls=walls, mean_pressures=mean_pressures, surface=surface,
                        E_star=E_star, tol=tol, method=method, max_iter=max_iter, length_unit=length_unit)
    workers = None if workers is None else check_int("workers", workers)
    threads = 1 if threads_per_worker is None else check_int("threads_per_worker", threads_per_worker)
    if not serial:
        try:
            importlib.import_module("dask.distributed")
        except ImportError as exc:
            raise ImportError('run_ensemble on a cluster needs Dask: pip install "diffusion-pr[ensemble]" '
                              "(or pass serial=True)") from exc
    store = Path(store)
    if store.exists() and not store.is_dir():
        raise ValueError(f"store must be a directory; {str(store)!r} is a file")
    check_writable_dir("store", store)
    if scheduler is not None and client is None and not serial:
        _probe_scheduler(scheduler)
    done = store_keys(store)
    todo = [c for c in cases if case_key(c) not in done]
    if command is None:
        command = (f"gfmd_ref.run_ensemble({str(store)!r}, n={n!r}, seeds={seeds!r}, walls={walls!r}, "
                   f"mean_pressures={mean_pressures!r}, surface={surface!r}, E_star={E_star!r}, tol={tol!r}, "
                   f"method={method!r})")
    prov = dict(command=command, code=code_version(), run_started=now_iso())
    tally = _Tally("ensemble", store, len(cases), len(todo),
                   dict(command=command, started=prov["run_started"], code=prov["code"], length_unit=length_unit,
                        zeta_unit="grid spacings of each record's grid (L = n)"),
                   progress, verbose, stream, "case", smoothing=0.0, desc="gfmd ensemble")
    sched, own = "serial (this process)", ()
    try:
        if serial or not todo:
            for c in todo:
                tally.add(case_label(c), lambda: solve_case(c, str(store), prov, threads))
        else:
            from dask.distributed import Client, as_completed

            if client is not None:
                sched = f"client {getattr(client, 'scheduler', None) and client.scheduler.address}"
            elif scheduler is not None:
                client, sched = Client(scheduler), f"scheduler {scheduler}"
                own = (client,)
            else:
                client, cluster, sched = _local_cluster(workers, threads)
                own = (client, cluster)
            futs = {client.submit(solve_case, c, str(store.resolve()), prov, threads, key=f"gfmd-case-{case_key(c)}",
                                  pure=False): c for c in todo}
            try:
                for f in as_completed(list(futs)):
                    tally.add(case_label(futs[f]), f.result)
            except BaseException:
                client.cancel(list(futs))  # interrupted: do not leave cases running on a shared cluster
                raise
    finally:
        tally.close()
        for obj in own:
            obj.close()
    return tally.finish(sched)


def ingest_fields(field_dir, store, *, surface: Optional[EnsembleSurface] = None, method: str = "auto",
                  field_command: str = "", command: Optional[str] = None, progress: bool = True,
                  verbose: bool = True, stream=None) -> EnsembleRun:
    """Reduce saved pressure fields into store records, exactly as a live case would.

    Each ``*.npz`` of ``field_dir`` holds ``pressure`` (the full field) and ``meta`` (JSON
    with ``n``, ``seed``, ``zeta``, ``length``, ``tol``, ``E_star``, ``mean_pressure``,
    ``converged``, ``residual``, ``iterations``, ``wall_time``, ``code``), as written by
    jobs that call ``solve_contact(fig1_surface(n, seed), ...)``. The record gets the key
    of the live case with the same parameters (``method`` as requested, default "auto"),
    so a later :func:`run_ensemble` of those cases skips them; its provenance says
    ``source="ingested"``, the field file and ``field_command``. The surface is
    regenerated from the seed (for the spectrum) and checked against the field's grid.
    Cases already in the store are skipped.
    """
    surface = FIG1_SURFACE if surface is None else surface
    field_dir, store = Path(field_dir), Path(store)
    if not field_dir.is_dir():
        raise ValueError(f"field_dir must be an existing directory; got {str(field_dir)!r}")
    files = sorted(p for p in field_dir.glob("*.npz") if not p.name.endswith(".tmp.npz"))
    if not files:
        raise ValueError(f"field_dir {str(field_dir)!r} holds no *.npz field")
    done = store_keys(store)
    command = f"gfmd_ref.ingest_fields({str(field_dir)!r}, {str(store)!r})" if command is None else command
    base = dict(command=command, code=code_version(), run_started=now_iso())
    todo = []
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
        params = build_cases(n=int(meta["n"]), seeds=[int(meta["seed"])],
                             walls=["hard" if meta["zeta"] is None else float(meta["zeta"])],
                             mean_pressures=float(meta["mean_pressure"]), surface=surface,
                             E_star=float(meta["E_star"]), tol=float(meta["tol"]), method=method)[0]
        if float(meta["length"]) != float(params["n"]):
            raise ValueError(f"{f.name}: length {float(meta['length'])} != n {params['n']} (ensembles use L = n)")
        if case_key(params) not in done:
            todo.append((f, meta, params))

    def ingest(f, meta, params) -> dict:
        with np.load(f, allow_pickle=False) as z:
            pressure = np.array(z["pressure"], dtype=np.float64)
        if pressure.shape != (params["n"], params["n"]):
            raise ValueError(f"field shape {pressure.shape} != ({params['n']}, {params['n']})")
        prov = dict(base, source="ingested", field_file=str(f.resolve()), field_command=field_command,
                    field_code=meta.get("code"), converged=bool(meta["converged"]), residual=float(meta["residual"]),
                    iterations=int(meta["iterations"]), wall_time=float(meta["wall_time"]),
                    method=meta.get("method"), host=host(), created=now_iso())
        _store_case(store, params, pressure, case_surface(params), prov)
        return prov

    tally = _Tally("ingest", store, len(files), len(todo),
                   dict(command=command, started=base["run_started"], code=base["code"], ingested_from=str(field_dir),
                        field_command=field_command), progress, verbose, stream, "field", desc="ingest")
    for f, meta, params in todo:
        tally.add(f.name, lambda: ingest(f, meta, params))
    tally.close()
    return tally.finish("ingest (this process)")
