"""The finite-volume operator of ``dPr/dtau = d^2(f Pr)/dp^2 - d/dp(a Pr)`` on a grid.

State ``y = [z, m_0, ..., m_{n-1}]``: ``z`` the probability absorbed at the
wall ``p_wall`` (0 where the wall is reached, the floor otherwise), ``m_i`` the
probability in cell ``i``.  With cell centres ``c_i``, widths ``h_i`` and
``u_i = m_i / h_i``, the flux through the face between cells ``i`` and ``i+1``
is ``-(f_{i+1} u_{i+1} - f_i u_i) / (c_{i+1} - c_i) + a_face (u_i + u_{i+1}) / 2``
(the central face value FiPy uses too; second order on the smoothly graded grids); through the wall face ``-(f_0 u_0 - 0)/(c_0 - p_wall)``
(``f Pr = 0`` at the wall, Feller's exit condition) plus the drift's outflow
``min(a_wall, 0) u_0``; nothing leaves through ``p_max``.  The matrix is
tridiagonal (``z`` couples to ``m_0`` only), total probability
``z + sum m_i`` is conserved exactly and, without drift,
``sum c_i m_i + p_wall z`` too (summation by parts).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["bands", "centres"]


def centres(edges: np.ndarray) -> np.ndarray:
    """Cell midpoints (pressure)."""
    return 0.5 * (edges[1:] + edges[:-1])


def bands(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray] = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-, main and super-diagonal of the operator acting on ``[z, m_0..m_{n-1}]``.

    Parameters
    ----------
    edges : ndarray, shape (n+1,)
        Cell edges (pressure), ``edges[0]`` the wall.
    f_c : ndarray, shape (..., n)
        ``f`` at the cell centres (dimensionless), >= 0.  Leading axes (e.g. one
        row per stage) give one operator per row.
    a_faces : ndarray, shape (..., n), optional
        Drift at the faces ``edges[0..n-1]`` (the wall face and the interior
        faces; pressure per unit tau); the top face carries no flux.

    Returns
    -------
    lower, diag, upper : ndarray, shapes (..., n), (..., n+1), (..., n)
    """
    f_c = np.asarray(f_c, dtype=float)
    h = np.diff(edges)
    c = centres(edges)
    n = c.size
    lead = f_c.shape[:-1]
    g = f_c / h  # m -> f u
    k_int = 1.0 / np.diff(c)  # inverse centre distances of the interior faces
    lower = np.zeros(lead + (n,))  # entry (row r+1, col r) of the (n+1)x(n+1) matrix
    diag = np.zeros(lead + (n + 1,))
    upper = np.zeros(lead + (n,))  # entry (row r, col r+1)
    # interior face i+1/2: diffusive flux J = -(g_{i+1} m_{i+1} - g_i m_i)/d; m_i' -= J, m_{i+1}' += J
    left = k_int * g[..., :-1]
    right = k_int * g[..., 1:]
    diag[..., 1:-1] -= left
    upper[..., 1:] += right
    diag[..., 2:] -= right
    lower[..., 1:] += left
    # wall face: outflow f_0 u_0 / (c_0 - p_wall) from m_0 into z
    out = g[..., 0] / (c[0] - edges[0])
    diag[..., 1] -= out
    upper[..., 0] += out
    if a_faces is not None:
        a_faces = np.asarray(a_faces, dtype=float)
        # interior faces: G = a (u_i + u_{i+1}) / 2, u = m / h; m_i' -= G, m_{i+1}' += G
        ai = a_faces[..., 1:]
        cl = ai * (0.5 / h[:-1])
        cr = ai * (0.5 / h[1:])
        diag[..., 1:-1] -= cl
        upper[..., 1:] -= cr
        lower[..., 1:] += cl
        diag[..., 2:] += cr
        # wall face: outflow only
        aw = np.minimum(a_faces[..., 0], 0.0)
        diag[..., 1] += aw / h[0]
        upper[..., 0] -= aw / h[0]
    return lower, diag, upper


def state_bands(lower_m: np.ndarray, diag_m: np.ndarray, upper_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bands on ``[z, m_0..m_{n-1}]`` from an operator on the cell masses alone.

    A library assembles ``dm/dtau = L_m m`` (mass leaves through the wall
    face only); the absorbed-mass row is ``z' = -(column sum of L_m at cell 0)``
    so that ``z + sum m`` is conserved exactly, as in :func:`bands`.
    """
    n = diag_m.size
    lower = np.zeros(n)
    diag = np.zeros(n + 1)
    upper = np.zeros(n)
    lower[1:] = lower_m
    diag[1:] = diag_m
    upper[1:] = upper_m
    upper[0] = -(diag_m[0] + (lower_m[0] if n > 1 else 0.0))
    return lower, diag, upper


def probe_bands(apply, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-, main and super-diagonal of a tridiagonal linear map ``apply`` (3 probes).

    ``apply(m) -> dm/dtau`` on arrays of length ``n``; columns ``j = k mod 3``
    are probed together (their rows do not overlap in a tridiagonal matrix).
    """
    lower = np.zeros(n - 1)
    diag = np.zeros(n)
    upper = np.zeros(n - 1)
    idx = np.arange(n)
    for k in range(3):
        e = (idx % 3 == k).astype(float)
        r = np.asarray(apply(e), dtype=float)
        cols = idx[idx % 3 == k]
        diag[cols] = r[cols]
        below = cols[cols + 1 < n]
        lower[below] = r[below + 1]  # entry (j+1, j)
        above = cols[cols >= 1]
        upper[above - 1] = r[above - 1]  # entry (j-1, j)
    return lower, diag, upper
