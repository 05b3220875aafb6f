"""Real 2-D FFTs of the solvers: Fourier multipliers applied to real fields (scipy.fft).

``rfft2``, a real multiplier (``2/(q E*)`` or ``q E*/2``) on the half spectrum, ``irfft2``.
:meth:`FFTPair.apply_route` writes into a caller's array and returns the input-output dot
product by Parseval; ``float32`` data and multiplier run in single precision.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft
from numba import njit

__all__ = ["FFTPair", "spectral_multiply", "spectral_scale"]


@njit(cache=True, error_model="numpy")
def spectral_multiply(spec, mult, n_last):
    """``spec *= mult`` for the half spectrum of a real ``(n0, n_last)`` field ``x`` and
    a real multiplier; returns ``sum_k w_k mult_k |X_k|^2`` (``w_k`` = 1 on the columns
    that are their own mirror, 2 elsewhere), which by Parseval is ``sum_i x_i y_i`` for
    ``y = irfft2(mult X) n0 n_last``. Real arithmetic gives numpy's values bit for bit;
    two accumulators per row shorten the add chain."""
    n0, nh = spec.shape
    last = nh - 1 if n_last % 2 == 0 else nh  # the Nyquist column has weight 1
    s = 0.0
    for i in range(n0):
        x = spec[i, 0]
        m = mult[i, 0]
        e = m * (x.real * x.real + x.imag * x.imag)
        spec[i, 0] = complex(x.real * m, x.imag * m)
        a0 = 0.0
        a1 = 0.0
        j = 1
        while j + 1 < last:
            x = spec[i, j]
            m = mult[i, j]
            a0 += m * (x.real * x.real + x.imag * x.imag)
            spec[i, j] = complex(x.real * m, x.imag * m)
            x = spec[i, j + 1]
            m = mult[i, j + 1]
            a1 += m * (x.real * x.real + x.imag * x.imag)
            spec[i, j + 1] = complex(x.real * m, x.imag * m)
            j += 2
        if j < last:
            x = spec[i, j]
            m = mult[i, j]
            a0 += m * (x.real * x.real + x.imag * x.imag)
            spec[i, j] = complex(x.real * m, x.imag * m)
        for j in range(last, nh):
            x = spec[i, j]
            m = mult[i, j]
            e += m * (x.real * x.real + x.imag * x.imag)
            spec[i, j] = complex(x.real * m, x.imag * m)
        s += e + 2.0 * (a0 + a1)
    return s


@njit(cache=True, error_model="numpy")
def spectral_scale(spec, mult):
    """``spec *= mult`` (real multiplier, half spectrum), numpy's values bit for bit."""
    sf = spec.ravel()
    mf = mult.ravel()
    for k in range(sf.size):
        x = sf[k]
        m = mf[k]
        sf[k] = complex(x.real * m, x.imag * m)


class FFTPair:
    """``rfft2``/``irfft2`` on a real grid of ``shape`` with ``threads`` workers."""

    def __init__(self, shape: tuple, threads: int = 1):
        self.shape = tuple(shape)
        self.threads = threads

    def rfft(self, x: np.ndarray) -> np.ndarray:
        return sfft.rfft2(x, workers=self.threads)

    def irfft(self, X: np.ndarray) -> np.ndarray:
        return sfft.irfft2(X, s=self.shape, workers=self.threads)

    def apply(self, mult: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``irfft2(mult * rfft2(x))``: a Fourier multiplier applied to a real field (a new array)."""
        out = np.empty(self.shape)
        self.apply_route(mult / (self.shape[0] * self.shape[1]), x, out, dot=False)
        return out

    def apply_route(self, mult_n: np.ndarray, src: np.ndarray, dst: np.ndarray, dot: bool = True) -> float:
        """``dst = irfft2(mult_n * rfft2(src)) * n^2`` (the normalisation folded into the
        multiplier ``mult_n = mult / n^2``; ``src`` is kept unless it is ``dst``). ``float32``
        arrays and multiplier run in single precision. Returns ``src . dst`` by Parseval
        (summed in double) with ``dot``, else NaN (the multiply skips the sum)."""
        X = sfft.rfft2(src, workers=self.threads)
        if dot:
            out = spectral_multiply(X, mult_n, self.shape[1])
        else:
            spectral_scale(X, mult_n)
            out = math.nan
        dst[...] = sfft.irfft2(X, s=self.shape, workers=self.threads, overwrite_x=True, norm="forward")
        return out
