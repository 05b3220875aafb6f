"""The elastic half-space on the ``rfft2`` grid of one periodic cell."""
from __future__ import annotations

import numpy as np

from ..fft import FFTPair


class Elastic:
    """Green's function of an elastic half-space on an ``(nx, ny)`` grid of sides ``(Lx, Ly)``.

    ``n`` and ``length`` are an int and a float (square cell) or pairs. Each Fourier mode
    ``q != 0`` of the surface displacement is a spring of stiffness ``K = q E*/2`` per unit
    area [pressure/length]; ``G = 2/(q E*)`` is its inverse (``G = 0`` at ``q = 0``), ``Gn =
    G/(nx ny)`` the multiplier of :meth:`~gfmd_ref.fft.FFTPair.apply_route`. ``w`` weighs the
    half spectrum in sums over the full one, ``g_diag`` is the real-space diagonal of ``G``
    [length/pressure]; ``q1 = 2 pi / max(Lx, Ly)`` is the smallest wavenumber.
    """

    def __init__(self, n, length, E_star: float, threads: int = 1):
        nx, ny = (n, n) if np.ndim(n) == 0 else (int(n[0]), int(n[1]))
        lx, ly = (length, length) if np.ndim(length) == 0 else (float(length[0]), float(length[1]))
        self.shape, self.size, self.E_star = (nx, ny), nx * ny, E_star
        kx = 2.0 * np.pi * np.fft.fftfreq(nx, d=lx / nx)
        ky = 2.0 * np.pi * np.fft.rfftfreq(ny, d=ly / ny)
        q = np.sqrt(kx[:, None] ** 2 + ky[None, :] ** 2)
        self.K = 0.5 * E_star * q
        self.G = np.where(q > 0, 2.0 / (E_star * np.where(q > 0, q, 1.0)), 0.0)
        self.Gn = self.G / self.size
        self.q1 = 2.0 * np.pi / max(lx, ly)
        self.w = np.full(q.shape, 2.0)
        self.w[:, 0] = 1.0
        if ny % 2 == 0:
            self.w[:, -1] = 1.0
        self.g_diag = float(np.sum(self.w * self.G)) / self.size
        self.fft = FFTPair(self.shape, threads)
        self.rfft, self.irfft, self.apply = self.fft.rfft, self.fft.irfft, self.fft.apply
