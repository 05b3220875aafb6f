"""The finite-volume operator of ``dPr/dtau = d^2(f Pr)/dp^2 - d/dp(a Pr)`` on a grid.

State ``y = [z, m_0, ..., m_{n-1}]``: ``z`` the probability absorbed at ``p_wall``, ``m_i`` the probability in
cell ``i`` (centre ``c_i``, width ``h_i``, ``u_i = m_i / h_i``).  The flux through the face between cells ``i``
and ``i+1`` is ``-(f_{i+1} u_{i+1} - f_i u_i) / (c_{i+1} - c_i) + a_face ((1/2 + s) u_i + (1/2 - s) u_{i+1})``:
central (``s = 0``, second order) where the cell Peclet number ``|Pe| <= 2``, leaning upwind beyond
(:func:`fitted_weight`) so that the spectrum stays real (CRAM holds on the negative real axis).  Closure and
balance drifts keep the central value (``fitted=False``).  The wall face carries ``-(f_0 u_0)/(c_0 - p_wall)``
(``f Pr = 0`` at the wall, Feller's exit condition) plus the drift's flux, clipped to an outflow
(:func:`wall_drift`); nothing leaves through ``p_max``.  The matrix is tridiagonal, ``z + sum m_i`` is
conserved exactly and, without drift, ``sum c_i m_i + p_wall z`` too (summation by parts).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["bands", "centres", "fitted_weight", "wall_drift", "wall_drift_rate"]


def centres(edges: np.ndarray) -> np.ndarray:
    """Cell midpoints (pressure)."""
    return 0.5 * (edges[1:] + edges[:-1])


def fitted_weight(shift: np.ndarray, f_min: np.ndarray) -> np.ndarray:
    """The drift's upwinding weight ``s = sign(Pe) max(0, 1/2 - 1/|Pe|)`` in ``[-1/2, 1/2]`` of ``Pe = shift /
    f_min``: the smallest that keeps a face's off-diagonal entries non-negative (the hybrid scheme of D. B.
    Spalding, Int. J. Numer. Meth. Eng. 4, 551 (1972)).

    ``shift``: drift times centre distance at the face, ``a (c_{i+1} - c_i)``; ``f_min``: the smaller ``f`` of the
    face's two cells, >= 0 (both pressure^2 per unit tau).
    """
    shift, f_min = np.broadcast_arrays(np.asarray(shift, dtype=float), np.asarray(f_min, dtype=float))
    x = np.abs(shift)
    out = np.zeros(shift.shape)
    big = x > 2.0 * f_min
    out[big] = 0.5 - f_min[big] / x[big]
    return np.where(shift < 0.0, -out, out)


def bands(edges: np.ndarray, f_c: np.ndarray, a_faces: Optional[np.ndarray] = None, fitted: bool = True,
          c: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-, main and super-diagonal of the operator acting on ``[z, m_0..m_{n-1}]``.

    Parameters
    ----------
    edges : ndarray, shape (n+1,)
        Cell edges (pressure), ``edges[0]`` the wall.
    f_c : ndarray, shape (..., n)
        ``f`` at the cell centres (dimensionless), >= 0; leading axes give one operator per row (stage).
    a_faces : ndarray, shape (..., n), optional
        Drift at the faces ``edges[0..n-1]`` (pressure per unit tau); the top face carries no flux.
    fitted : bool or ndarray of bool, shape (...)
        Interior faces take :func:`fitted_weight` (default); False: the central value.  Per row or for all.
    c : ndarray, shape (n,), optional
        The cell centres :func:`centres` gives, where the caller has them.

    Returns
    -------
    lower, diag, upper : ndarray, shapes (..., n), (..., n+1), (..., n)
    """
    f_c = np.asarray(f_c, dtype=float)
    h = edges[1:] - edges[:-1]
    c = centres(edges) if c is None else c
    n = c.size
    lead = f_c.shape[:-1]
    g = f_c / h  # m -> f u
    k_int = 1.0 / (c[1:] - c[:-1])  # inverse centre distances of the interior faces
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
        # interior faces: G = a ((1/2 + s) u_i + (1/2 - s) u_{i+1}), u = m / h; m_i' -= G, m_{i+1}' += G
        ai = a_faces[..., 1:]
        cl = ai * (0.5 / h[:-1])
        cr = ai * (0.5 / h[1:])
        fitted = np.asarray(fitted, dtype=bool)
        if fitted.any():  # the weight where it is not 0 (the central value stays bit for bit)
            s = fitted_weight(ai / k_int, np.minimum(f_c[..., :-1], f_c[..., 1:])) * fitted[..., None]
            cl = np.where(s != 0.0, ai * (0.5 + s) / h[:-1], cl)
            cr = np.where(s != 0.0, ai * (0.5 - s) / h[1:], cr)
        diag[..., 1:-1] -= cl
        upper[..., 1:] -= cr
        lower[..., 1:] += cl
        diag[..., 2:] += cr
        wall_drift(diag, upper, out, a_faces[..., 0], h[0], edges[0])
    return lower, diag, upper


def wall_drift(diag: np.ndarray, upper: np.ndarray, out, a_wall, h_0: float, p_wall: float = 0.0) -> None:
    """Add the drift's flux through the wall face to bands on ``[z, m_0..m_{n-1}]`` (in place).

    ``out`` is cell 0's diffusive outflow rate (per unit of ``m_0``), ``a_wall`` the drift on the wall face
    (pressure per unit tau), ``h_0`` cell 0's width.  The net flux ``(a_wall - out h_0) u_0`` is clipped to an
    outflow: where the drift holds probability off the wall (an entrance boundary) nothing is absorbed, and
    nothing flows back out of ``z``.  A bottom ``p_wall > 0`` (wall not reached) absorbs what crosses it.
    """
    rate = wall_drift_rate(out, a_wall, h_0, p_wall)
    diag[..., 1] += rate
    upper[..., 0] -= rate


def wall_drift_rate(out, a_wall, h_0: float, p_wall: float = 0.0):
    """:func:`wall_drift`'s term of cell 0's rate per unit of ``m_0`` (1/tau): ``a_wall / h_0`` towards the wall,
    ``min(a_wall / h_0, out)`` away from a wall at 0, nothing away from a bottom ``p_wall > 0``."""
    a_wall = np.asarray(a_wall, dtype=float)
    towards = np.minimum(a_wall, 0.0) / h_0
    if p_wall > 0.0:
        return towards
    return towards + np.minimum(np.maximum(a_wall, 0.0) / h_0, out)


def state_bands(lower_m: np.ndarray, diag_m: np.ndarray, upper_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bands on ``[z, m_0..m_{n-1}]`` from an operator ``L_m`` on the cell masses alone.

    The absorbed-mass row is ``z' = -(column sum of L_m at cell 0)``, so ``z + sum m`` is conserved exactly.
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
    """Sub-, main and super-diagonal of a tridiagonal linear map ``apply(m) -> dm/dtau`` on length ``n``.

    Columns ``j = k mod 3`` are probed together (their rows do not overlap in a tridiagonal matrix).
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
