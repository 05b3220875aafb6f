"""Real 2-D FFT pairs for the solvers: planned FFTW where available, else scipy.

At 1024^2 one ``rfft2`` + ``irfft2`` pair costs about 21 ms with scipy's
pocketfft on this 2-core machine and 5.7 ms with an FFTW plan made with
``FFTW_MEASURE`` (pyfftw); the FFTs dominate the constrained-CG iteration, so
the planned pair makes the hard-wall solver about twice as fast.  Planning is
a one-time, visible cost (about 2 s at 1024^2, bounded by
``PLANNING_TIMELIMIT``), cached per grid size for the life of the process and
reported by :func:`fft_pair` so that a caller can warm it up.  Small grids
(below ``FFTW_MIN_N``) and machines without pyfftw use scipy.fft.  Set the
environment variable ``GFMD_REF_FFT=scipy`` to force scipy.
"""
from __future__ import annotations

import os
import time
from typing import Any, Dict, Tuple

import numpy as np
import scipy.fft as sfft

#: ``workers`` passed to scipy.fft (-1: all cores; ``GFMD_REF_FFT_THREADS`` overrides).
FFT_WORKERS = -1


def fft_threads() -> int:
    """Threads per FFT: ``GFMD_REF_FFT_THREADS`` if set (the ensemble runner sets 1 per
    worker process), else all cores. Read when a grid size is first planned."""
    v = os.environ.get("GFMD_REF_FFT_THREADS", "")
    return max(1, int(v)) if v.strip() else max(1, os.cpu_count() or 1)


#: grids smaller than this use scipy (planning would not pay off).
FFTW_MIN_N = 256
#: seconds FFTW may spend planning one transform (the best plan found so far is used).
PLANNING_TIMELIMIT = 5.0


class ScipyPair:
    """``rfft2``/``irfft2`` on an ``(n, n)`` grid with scipy.fft (pocketfft, threaded)."""

    name = "scipy"

    def __init__(self, shape: Tuple[int, int]):
        self.shape = shape
        self.workers = fft_threads() if os.environ.get("GFMD_REF_FFT_THREADS", "").strip() else FFT_WORKERS

    def rfft(self, x: np.ndarray) -> np.ndarray:
        return sfft.rfft2(x, workers=self.workers)

    def irfft(self, X: np.ndarray) -> np.ndarray:
        return sfft.irfft2(X, s=self.shape, workers=self.workers)

    def apply(self, mult: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``irfft2(mult * rfft2(x))``: a Fourier multiplier applied to a real field."""
        X = sfft.rfft2(x, workers=self.workers)
        X *= mult
        return sfft.irfft2(X, s=self.shape, workers=self.workers, overwrite_x=True)


class FFTWPair:
    """The same three operations with FFTW plans (pyfftw) on aligned buffers.

    Each call copies its input into the plan's buffer and returns a fresh
    array, so results never alias the buffers.  The inverse is normalised by
    ``1/n^2`` like scipy's.
    """

    name = "fftw"

    def __init__(self, shape: Tuple[int, int], threads: int):
        import pyfftw

        n0, n1 = shape
        self.shape = shape
        self._real = pyfftw.empty_aligned(shape, dtype="float64")
        self._spec = pyfftw.empty_aligned((n0, n1 // 2 + 1), dtype="complex128")
        flags = ("FFTW_MEASURE", "FFTW_DESTROY_INPUT")
        self._forward = pyfftw.FFTW(self._real, self._spec, axes=(0, 1), threads=threads, flags=flags,
                                    planning_timelimit=PLANNING_TIMELIMIT)
        self._backward = pyfftw.FFTW(self._spec, self._real, axes=(0, 1), direction="FFTW_BACKWARD",
                                     threads=threads, flags=flags, planning_timelimit=PLANNING_TIMELIMIT)
        self._scale = 1.0 / (n0 * n1)

    def rfft(self, x: np.ndarray) -> np.ndarray:
        self._real[...] = x
        self._forward.execute()
        return self._spec.copy()

    def irfft(self, X: np.ndarray) -> np.ndarray:
        self._spec[...] = X
        self._backward.execute()
        return self._real * self._scale

    def apply(self, mult: np.ndarray, x: np.ndarray) -> np.ndarray:
        self._real[...] = x
        self._forward.execute()
        self._spec *= mult
        self._backward.execute()
        return self._real * self._scale


_CACHE: Dict[Tuple[int, int], Any] = {}


def _want_fftw(n: int) -> bool:
    if os.environ.get("GFMD_REF_FFT", "").lower() == "scipy" or n < FFTW_MIN_N:
        return False
    try:
        import pyfftw  # noqa: F401
    except ImportError:
        return False
    return True


def fft_pair(shape: Tuple[int, int]) -> Tuple[Any, float]:
    """The FFT pair for ``shape`` and the seconds spent planning it now (0 if cached).

    Returns
    -------
    (pair, planning_time)
        ``pair.name`` is ``"fftw"`` or ``"scipy"``.
    """
    if shape in _CACHE:
        return _CACHE[shape], 0.0
    t0 = time.perf_counter()
    if _want_fftw(shape[0]):
        pair: Any = FFTWPair(shape, threads=fft_threads())
    else:
        pair = ScipyPair(shape)
    _CACHE[shape] = pair
    return pair, time.perf_counter() - t0
