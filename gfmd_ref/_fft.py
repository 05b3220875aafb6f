"""Real 2-D FFT pairs for the solvers: planned FFTW where available, else scipy.

The FFTs dominate every solver iteration (two to three ``rfft2`` + ``irfft2`` pairs
per preconditioned constrained-CG step), so they are planned once per grid size,
thread count and calling thread (``FFTW_MEASURE`` with pyfftw) and cached for the
life of the thread. The hard-wall solver keeps its state in the pair's work arrays
(:meth:`FFTWPair.work_array`) and transforms between them with
:meth:`FFTWPair.apply_route`: one pair and one multiply, no copy in or out, no
allocation, and the dot product of input and output by Parseval for free.
:meth:`FFTWPair.apply_into` (a copy in and a copy out) serves the other solvers.
Planning is a one-time, visible cost (about 2 s at 1024^2 with the work arrays,
bounded by ``PLANNING_TIMELIMIT`` per plan) reported by :func:`fft_pair` and
:func:`gfmd_ref.warm_up_fft` so that a caller can warm it up. Small grids (below
``FFTW_MIN_N``) and machines without pyfftw use scipy.fft. Set the environment
variable ``GFMD_REF_FFT=scipy`` to force scipy.

FFTW's wisdom (the plans it measured) is kept between processes in a file
(:func:`wisdom_path`: ``GFMD_REF_FFTW_WISDOM`` names it, ``off`` disables it; by
default ``$XDG_CACHE_HOME/gfmd_ref/`` or ``~/.cache/gfmd_ref/``), read before the first
plan of a process and rewritten (atomically) after a plan was measured: a later process
makes the same plans from it (``warm_up_fft(512)`` measured 1.10 s -> 0.17 s), hence the
same answers bit for bit. A file that cannot be read or written
is ignored: wisdom only saves time, it never changes what a transform computes.

Threads: ``DEFAULT_THREADS`` is 1, chosen by measurement on the 2-core
development machine while other jobs kept it loaded (``benchmarks/bench_gfmd.py
--part threads``, table in ``docs/gfmd.md``): one FFTW thread was faster than two
at every size from 256^2 to 2048^2 (two threads compete with the other processes
for the two cores).  On an idle multi-core machine pass ``threads=`` explicitly
(or set ``GFMD_REF_FFT_THREADS``).
"""
from __future__ import annotations

import math
import os
import threading
import time
from typing import Any, Dict, Optional, Tuple

import numpy as np
import scipy.fft as sfft

from ._kernels import spectral_multiply, spectral_scale

#: FFT threads used when a caller does not say (see module doc for the measurement).
DEFAULT_THREADS = 1
#: kept for backward compatibility: ``workers`` of scipy.fft when no thread count is given.
FFT_WORKERS = DEFAULT_THREADS
#: grids smaller than this use scipy (planning would not pay off).
FFTW_MIN_N = 256
#: seconds FFTW may spend planning one transform (the best plan found so far is used).
PLANNING_TIMELIMIT = 5.0
#: a plan made faster than this came from wisdom: nothing new to save
_WISDOM_NEW_PLAN_SECONDS = 0.02
_WISDOM_LOCK = threading.Lock()
_WISDOM_STATE = {"loaded": False, "imported": False}


def _cpu_tag() -> str:
    """A short tag of this processor's model (Linux: ``/proc/cpuinfo``; else the
    platform's processor string), so that machines of different kinds sharing a home
    directory keep their own plans."""
    import hashlib
    import platform

    model = platform.processor()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return hashlib.sha256(model.encode()).hexdigest()[:8]


def wisdom_path() -> Optional[str]:
    """The file FFTW's wisdom is kept in between processes, or None (``GFMD_REF_FFTW_WISDOM
    =off``). Its name carries the machine type, a tag of the processor model and the
    pyfftw version (wisdom of another FFTW build is not read)."""
    v = os.environ.get("GFMD_REF_FFTW_WISDOM", "").strip()
    if v.lower() in ("off", "0", "no", "false"):
        return None
    if v:
        return v
    import platform

    try:
        import pyfftw

        version = pyfftw.__version__
    except ImportError:  # pragma: no cover - only called with pyfftw
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "gfmd_ref",
                        f"fftw-wisdom-{platform.machine()}-{_cpu_tag()}-pyfftw{version}.json")


def _load_wisdom() -> None:
    """Read the wisdom file once per process (before the first plan); ignored if absent or unreadable."""
    with _WISDOM_LOCK:
        if _WISDOM_STATE["loaded"]:
            return
        _WISDOM_STATE["loaded"] = True
        path = wisdom_path()
        if path is None or not os.path.exists(path):
            return
        try:
            import json

            import pyfftw

            with open(path, encoding="ascii") as fh:
                data = json.load(fh)
            ok = pyfftw.import_wisdom(tuple(data[k].encode("ascii") for k in ("double", "single", "long")))
            _WISDOM_STATE["imported"] = bool(all(ok))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass  # wisdom only saves planning time


def _save_wisdom() -> None:
    """Write this process's wisdom to the wisdom file (a temporary file renamed over it, so a
    reader never sees half a file); ignored where the directory is not writable."""
    path = wisdom_path()
    if path is None:
        return
    try:
        import json
        import tempfile

        import pyfftw

        double, single, long = pyfftw.export_wisdom()
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        with _WISDOM_LOCK:
            fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path) or ".", suffix=".tmp")
            with os.fdopen(fd, "w", encoding="ascii") as fh:
                json.dump({"double": double.decode("ascii"), "single": single.decode("ascii"),
                           "long": long.decode("ascii")}, fh)
            os.replace(tmp, path)
    except (OSError, ValueError, UnicodeDecodeError):
        pass


def fft_threads() -> int:
    """Threads per FFT when a caller does not say: ``GFMD_REF_FFT_THREADS`` if set (the
    ensemble runner sets 1 per worker process), else :data:`DEFAULT_THREADS`."""
    v = os.environ.get("GFMD_REF_FFT_THREADS", "")
    return max(1, int(v)) if v.strip() else DEFAULT_THREADS


def check_threads(threads: Optional[int]) -> int:
    """``threads`` -> an int >= 1 (``None`` -> :func:`fft_threads`); ValueError otherwise."""
    if threads is None:
        return fft_threads()
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"threads must be an integer >= 1 (or None for the default); "
                         f"got {threads!r}")
    return int(threads)


def _multiply(spec: np.ndarray, mult: np.ndarray, n_last: int, dot: bool) -> float:
    """``spec *= mult`` in place; returns the Parseval dot of :func:`spectral_multiply` with
    ``dot``, else NaN (and the multiply skips it: :func:`spectral_scale`)."""
    if dot:
        return spectral_multiply(spec, mult, n_last)
    spectral_scale(spec, mult)
    return math.nan


class _Pair:
    """What both pairs share: the work arrays' bookkeeping (``_work``, ``work_array``)."""

    _work: Dict[int, np.ndarray]
    _single: Dict[int, Any]
    _defer_wisdom = False  # plans measured now are saved by make_work_arrays, once
    _wisdom_dirty = False
    #: seconds spent in the transforms (plan executions or scipy's ``rfft2``/``irfft2``, with the copies in and out
    #: where a method makes them) and in the spectral multiplies between them, summed over the pair's life (a
    #: solver reports its own share: ``info["fft_seconds"]``, ``info["multiply_seconds"]``). Timed inside a solve,
    #: the transforms run on the data as the iteration leaves them, which a benchmark of repeated raw pairs does not
    #: see (measured no slower at 1024^2 and 2048^2: docs/gfmd.md); four ``perf_counter`` calls per pair (about
    #: 0.3 us) are the price
    transform_seconds = 0.0
    multiply_seconds = 0.0

    def single_array(self, index: int = 0) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def apply_single(self, mult_n32: np.ndarray, src: int = 0, dst: Optional[int] = None,
                     dot: bool = False) -> float:  # pragma: no cover - overridden
        """:meth:`apply_route` in single precision between the single-precision work
        arrays ``src`` and ``dst`` (default: in place on ``src``; ``src`` is kept
        otherwise): ``dst = irfft2(mult_n32 * rfft2(src)) * n^2`` with ``float32`` data
        and a ``float32`` multiplier (for a preconditioner or a step length, whose
        rounding only perturbs a search). Returns ``src . dst`` by Parseval (summed in
        double) with ``dot``, else NaN."""
        raise NotImplementedError

    def work_array(self, index: int) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def _timed(self, t0: float, t1: float, t2: float) -> None:
        """Count one pair: forward ``t0 .. t1``, multiply ``t1 .. t2``, backward ``t2 ..`` now."""
        self.transform_seconds += (t1 - t0) + (time.perf_counter() - t2)
        self.multiply_seconds += t2 - t1

    def make_work_arrays(self, count: int, single: int = 0) -> float:
        """Make work arrays ``0 .. count-1`` and the single-precision ones ``0 .. single-1``
        (:meth:`single_array`) now; returns the seconds spent (0 if all were made)."""
        t0 = time.perf_counter()
        self._defer_wisdom = True  # FFTW: one wisdom file write for all the plans measured here
        try:
            new = [k for k in range(count) if k not in self._work]
            for k in new:
                self.work_array(k)
            new_single = [k for k in range(int(single)) if k not in self._single]
            for k in new_single:
                self.single_array(k)
        finally:
            self._defer_wisdom = False
            if self._wisdom_dirty:
                self._wisdom_dirty = False
                _save_wisdom()
        return time.perf_counter() - t0 if new or new_single else 0.0


class ScipyPair(_Pair):
    """``rfft2``/``irfft2`` on an ``(n, n)`` grid with scipy.fft (pocketfft)."""

    name = "scipy"

    def __init__(self, shape: Tuple[int, int], threads: int = DEFAULT_THREADS):
        self.shape = shape
        self.threads = threads
        self._work: Dict[int, np.ndarray] = {}
        self._single: Dict[int, np.ndarray] = {}

    def rfft(self, x: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        out = sfft.rfft2(x, workers=self.threads)
        self.transform_seconds += time.perf_counter() - t0
        return out

    def irfft(self, X: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        out = sfft.irfft2(X, s=self.shape, workers=self.threads)
        self.transform_seconds += time.perf_counter() - t0
        return out

    def apply(self, mult: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``irfft2(mult * rfft2(x))``: a Fourier multiplier applied to a real field."""
        t0 = time.perf_counter()
        X = sfft.rfft2(x, workers=self.threads)
        t1 = time.perf_counter()
        X *= mult
        t2 = time.perf_counter()
        out = sfft.irfft2(X, s=self.shape, workers=self.threads, overwrite_x=True)
        self._timed(t0, t1, t2)
        return out

    def apply_into(self, mult_n: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out = irfft2(mult_n * rfft2(x)) * n^2``: as :meth:`apply` with the
        normalisation ``1/n^2`` folded into the multiplier ``mult_n = mult / n^2``."""
        self.apply_route(mult_n, x, out)
        return out

    def work_array(self, index: int) -> np.ndarray:
        """Work array number ``index`` for :meth:`apply_route` (made once, then reused;
        its content is whatever the last user left)."""
        if index not in self._work:
            self._work[index] = np.zeros(self.shape)
        return self._work[index]

    def apply_route(self, mult_n: np.ndarray, src: np.ndarray, dst: np.ndarray, dot: bool = True) -> float:
        """``dst = irfft2(mult_n * rfft2(src)) * n^2`` (``src`` is kept unless it is
        ``dst``; any arrays of the grid's shape, work arrays or not); returns
        ``src . dst`` (by Parseval, see :func:`gfmd_ref._kernels.spectral_multiply`), or
        NaN with ``dot=False`` (then the multiply skips the dot)."""
        t0 = time.perf_counter()
        X = sfft.rfft2(src, workers=self.threads)
        t1 = time.perf_counter()
        out = _multiply(X, mult_n, self.shape[1], dot)
        t2 = time.perf_counter()
        dst[...] = sfft.irfft2(X, s=self.shape, workers=self.threads, overwrite_x=True,
                               norm="forward")
        self._timed(t0, t1, t2)
        return out

    def single_array(self, index: int = 0) -> np.ndarray:
        """Single-precision work array number ``index`` of :meth:`apply_single` (made
        once, then reused)."""
        if index not in self._single:
            self._single[index] = np.zeros(self.shape, dtype=np.float32)
        return self._single[index]

    def apply_single(self, mult_n32: np.ndarray, src: int = 0, dst: Optional[int] = None,
                     dot: bool = False) -> float:
        """See :meth:`_Pair.apply_single`."""
        w = self.single_array(src)
        t0 = time.perf_counter()
        X = sfft.rfft2(w, workers=self.threads)
        t1 = time.perf_counter()
        out = _multiply(X, mult_n32, self.shape[1], dot)
        t2 = time.perf_counter()
        self.single_array(src if dst is None else dst)[...] = sfft.irfft2(
            X, s=self.shape, workers=self.threads, overwrite_x=True, norm="forward")
        self._timed(t0, t1, t2)
        return out


class FFTWPair(_Pair):
    """The same operations with FFTW plans (pyfftw) on aligned buffers.

    :meth:`rfft`, :meth:`irfft` and :meth:`apply` copy their input into the plan's
    buffer and return a fresh array, so results never alias the buffers; the
    inverse is normalised by ``1/n^2`` like scipy's.  :meth:`apply_into` writes
    into a caller's array.
    """

    name = "fftw"

    def __init__(self, shape: Tuple[int, int], threads: int = DEFAULT_THREADS):
        import pyfftw

        _load_wisdom()
        t0 = time.perf_counter()
        n0, n1 = shape
        self.shape = shape
        self.threads = threads
        self._real = pyfftw.empty_aligned(shape, dtype="float64")
        self._spec = pyfftw.empty_aligned((n0, n1 // 2 + 1), dtype="complex128")
        flags = ("FFTW_MEASURE", "FFTW_DESTROY_INPUT")
        self._forward = pyfftw.FFTW(self._real, self._spec, axes=(0, 1), threads=threads, flags=flags,
                                    planning_timelimit=PLANNING_TIMELIMIT)
        self._backward = pyfftw.FFTW(self._spec, self._real, axes=(0, 1), direction="FFTW_BACKWARD",
                                     threads=threads, flags=flags, planning_timelimit=PLANNING_TIMELIMIT)
        self._scale = 1.0 / (n0 * n1)
        self._plans: Dict[int, Tuple[np.ndarray, Any, Any]] = {}
        self._work: Dict[int, np.ndarray] = {}
        self._single: Dict[int, Tuple[np.ndarray, Any, Any]] = {}
        self._spec32: Optional[np.ndarray] = None
        self._planned(t0)

    def _planned(self, t0: float) -> None:
        """Save the wisdom if the plans made since ``t0`` were measured (not read from
        wisdom); within :meth:`make_work_arrays`, once at its end."""
        if time.perf_counter() - t0 > _WISDOM_NEW_PLAN_SECONDS:
            if self._defer_wisdom:
                self._wisdom_dirty = True
            else:
                _save_wisdom()

    def rfft(self, x: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        self._real[...] = x
        self._forward.execute()
        out = self._spec.copy()
        self.transform_seconds += time.perf_counter() - t0
        return out

    def irfft(self, X: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        self._spec[...] = X
        self._backward.execute()
        out = self._real * self._scale
        self.transform_seconds += time.perf_counter() - t0
        return out

    def apply(self, mult: np.ndarray, x: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        self._real[...] = x
        self._forward.execute()
        t1 = time.perf_counter()
        self._spec *= mult
        t2 = time.perf_counter()
        self._backward.execute()
        out = self._real * self._scale
        self._timed(t0, t1, t2)
        return out

    def apply_into(self, mult_n: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out = irfft2(mult_n * rfft2(x)) * n^2`` (``mult_n = mult / n^2``), no allocation."""
        t0 = time.perf_counter()
        self._real[...] = x
        self._forward.execute()
        t1 = time.perf_counter()
        spectral_scale(self._spec, mult_n)
        t2 = time.perf_counter()
        self._backward.execute()
        out[...] = self._real
        self._timed(t0, t1, t2)
        return out

    def work_array(self, index: int) -> np.ndarray:
        """Work array number ``index``: an aligned real ``(n, n)`` array with its own
        plans (a forward one that keeps its input, a backward one into it), made once
        per pair and reused by every later solve (its content is whatever the last
        user left).

        The plans share this pair's spectrum buffer, so :meth:`apply_route` between
        work arrays costs one FFT pair and one multiply: no copy in, no copy out
        (measured 2-3 ms of a 12 ms :meth:`apply_into` at 1024^2 in a solve), and a
        field that must survive its transform (the pressure, a search direction) is
        transformed where it lies."""
        if index in self._work:
            return self._work[index]
        buf, fwd, bwd = self._planned_array("float64", self._spec)
        self._plans[id(buf)] = (buf, fwd, bwd)
        self._work[index] = buf
        return buf

    def _planned_array(self, dtype: str, spec: np.ndarray) -> Tuple[np.ndarray, Any, Any]:
        """A zeroed aligned ``(n, n)`` array of ``dtype`` with its plans into and out of
        ``spec`` (the forward keeps its input: as fast at 1024^2); the wisdom is saved if
        they were measured (:meth:`_planned`)."""
        import pyfftw

        t0 = time.perf_counter()
        buf = pyfftw.empty_aligned(self.shape, dtype=dtype)
        buf[...] = 0.0
        fwd = pyfftw.FFTW(buf, spec, axes=(0, 1), threads=self.threads, flags=("FFTW_MEASURE",),
                          planning_timelimit=PLANNING_TIMELIMIT)
        bwd = pyfftw.FFTW(spec, buf, axes=(0, 1), direction="FFTW_BACKWARD", threads=self.threads,
                          flags=("FFTW_MEASURE", "FFTW_DESTROY_INPUT"), planning_timelimit=PLANNING_TIMELIMIT)
        self._planned(t0)
        return buf, fwd, bwd

    def single_array(self, index: int = 0) -> np.ndarray:
        """Single-precision work array number ``index`` of :meth:`apply_single`: an
        aligned ``float32`` ``(n, n)`` array with its own plans into and out of the
        pair's single-precision spectrum buffer (made once per pair; the forward plan
        keeps its input)."""
        if index not in self._single:
            if self._spec32 is None:
                import pyfftw

                n0, n1 = self.shape
                self._spec32 = pyfftw.empty_aligned((n0, n1 // 2 + 1), dtype="complex64")
            self._single[index] = self._planned_array("float32", self._spec32)
        return self._single[index][0]

    def apply_single(self, mult_n32: np.ndarray, src: int = 0, dst: Optional[int] = None,
                     dot: bool = False) -> float:
        """See :meth:`_Pair.apply_single`."""
        self.single_array(src)
        self.single_array(src if dst is None else dst)
        t0 = time.perf_counter()
        self._single[src][1].execute()
        t1 = time.perf_counter()
        out = _multiply(self._spec32, mult_n32, self.shape[1], dot)
        t2 = time.perf_counter()
        self._single[src if dst is None else dst][2].execute()
        self._timed(t0, t1, t2)
        return out

    def _plans_of(self, buf: np.ndarray) -> Tuple[np.ndarray, Any, Any]:
        owner, fwd, bwd = self._plans.get(id(buf), (None, None, None))
        if owner is not buf:
            raise ValueError("apply_route needs work arrays made by this pair's work_array()")
        return owner, fwd, bwd

    def apply_route(self, mult_n: np.ndarray, src: np.ndarray, dst: np.ndarray, dot: bool = True) -> float:
        """``dst = irfft2(mult_n * rfft2(src)) * n^2`` (``src`` is kept unless it is
        ``dst``); both must be :meth:`work_array` s of this pair (ValueError otherwise).
        Returns ``src . dst`` (by Parseval, see
        :func:`gfmd_ref._kernels.spectral_multiply`), or NaN with ``dot=False`` (then
        the multiply skips the dot: :func:`gfmd_ref._kernels.spectral_scale`)."""
        fwd = self._plans_of(src)[1]
        bwd = self._plans_of(dst)[2]
        t0 = time.perf_counter()
        fwd.execute()
        t1 = time.perf_counter()
        out = _multiply(self._spec, mult_n, self.shape[1], dot)
        t2 = time.perf_counter()
        bwd.execute()
        self._timed(t0, t1, t2)
        return out


#: pairs per thread: a pair's buffers and work arrays hold a solve's state, so two
#: threads of one process (a Dask worker with several threads) must not share them
_LOCAL = threading.local()


def _cache() -> Dict[Tuple[Tuple[int, int], int], Any]:
    if not hasattr(_LOCAL, "pairs"):
        _LOCAL.pairs = {}
    return _LOCAL.pairs


def _want_fftw(n: int) -> bool:
    if os.environ.get("GFMD_REF_FFT", "").lower() == "scipy" or n < FFTW_MIN_N:
        return False
    try:
        import pyfftw  # noqa: F401
    except ImportError:
        return False
    return True


def fft_pair(shape: Tuple[int, int], threads: Optional[int] = None) -> Tuple[Any, float]:
    """The FFT pair for ``shape`` and the seconds spent planning it now (0 if cached).

    Parameters
    ----------
    shape : (int, int)
    threads : int, optional
        FFT threads (default :data:`DEFAULT_THREADS`).

    Returns
    -------
    (pair, planning_time)
        ``pair.name`` is ``"fftw"`` or ``"scipy"``.
    """
    threads = check_threads(threads)
    key = (tuple(shape), threads)
    cache = _cache()
    if key in cache:
        return cache[key], 0.0
    t0 = time.perf_counter()
    if _want_fftw(shape[0]):
        pair: Any = FFTWPair(tuple(shape), threads=threads)
    else:
        pair = ScipyPair(tuple(shape), threads=threads)
    cache[key] = pair
    return pair, time.perf_counter() - t0
