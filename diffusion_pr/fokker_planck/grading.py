"""The grid family adapted after the first level's Richardson differences: the logarithmic grading towards the
wall regraded (:func:`_regraded`) or the monitor remapped (:func:`_remapped`)."""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional

import numpy as np

from .domain import Prepared
from .grid import GridSpec, Remap

#: the largest weight of the logarithmic grading towards the wall (the regrading's candidates)
WALL_GRADING_MAX = 10.0
#: regrade only where the predicted cells fall by at least this fraction
REGRADE_GAIN = 0.15
#: candidate factors on ``c_wall`` (the weight of the logarithmic grading)
REGRADE_FACTORS = (0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, 1.5, 2.0)
#: candidate inner scales of the logarithmic grading (``GridSpec.wall_depth``), as fractions of the way from the
#: floor to ``p0`` in ``ln p``
REGRADE_DEPTHS = (0.2, 0.35, 0.5, 0.65, 0.8)
#: the remapped monitor (:func:`_remapped`): knots of its density's spline, the largest ratio of its densities,
#: and the share of the regrading's best cells it must undercut
REMAP_KNOTS = 12
REMAP_MAX_RATIO = 16.0
REMAP_PREFERENCE = 0.9


def _regradable(prep: Prepared) -> bool:
    """Whether the grading towards the wall may change: ``c_wall > 0``, the depth below the floor fixed, no exit
    wall."""
    return prep.spec.c_wall > 0.0 and not prep.depth_adaptive and not prep.reached


def _wall_depth(spec: GridSpec, fraction: float) -> float:
    """``GridSpec.wall_depth`` for ``fraction`` of the way from the floor to ``p0`` in ``ln p`` (0: the default)."""
    if fraction <= 0.0 or spec.p_wall <= 0.0:
        return 0.0
    return spec.p_wall * (spec.p0 / spec.p_wall) ** fraction


def _depth_fraction(spec: GridSpec) -> float:
    """The inverse of :func:`_wall_depth`: where the logarithmic grading of ``spec`` ends, as that fraction."""
    if spec.wall_depth <= 0.0 or spec.p_wall <= 0.0:
        return 0.0
    return math.log(spec.wall_depth / spec.p_wall) / math.log(spec.p0 / spec.p_wall)


def _cell_errors(diff: np.ndarray, j: int) -> np.ndarray:
    """The first level's Richardson differences per cell of the N grid (magnitudes), the lumped entry spread evenly
    over the ``j`` cells below the floor."""
    d = np.abs(np.asarray(diff, dtype=float))
    return np.concatenate((np.full(j, d[0] / j) if j > 0 else np.empty(0), d[1:]))


def _remapped(spec: GridSpec, edges: np.ndarray, diff: np.ndarray, j: int) -> Optional[tuple]:
    """``(spec, cell factor)``: ``spec`` remapped (:class:`~.grid.Remap`) so that the first level's errors are
    about equidistributed, and the ratio of the cells it needs for that error to those ``spec`` needs.

    A cell's error falls like its width to the fourth power, so for a given total the fewest cells have widths
    ``~ e_i^(-1/5)`` (Lagrange): the new monitor's density is ``D ~ e^(1/5)``, smoothed at :data:`REMAP_KNOTS`
    knots and capped at :data:`REMAP_MAX_RATIO`.  The factor is ``(sum e_i rho_i^4 / sum e_i)^(1/4)``, ``rho_i``
    the new width over the old.  None where the spline is not safely positive or the errors are not finite.
    """
    e = _cell_errors(diff, j)
    if not np.isfinite(e).all() or e.sum() <= 0.0 or e.size + 1 != edges.size:
        return None
    base0 = float(spec.phi(spec.p_wall))
    v_edges = spec.phi(edges) - base0
    v_c = 0.5 * (v_edges[:-1] + v_edges[1:])
    smooth = np.maximum(e, 0.5 * np.maximum(np.concatenate((e[1:], (0.0,))), np.concatenate(((0.0,), e[:-1]))))
    log_d = 0.2 * np.log(np.maximum(smooth, 1e-12 * smooth.max()))
    total = float(v_edges[-1])
    knots = np.linspace(0.0, total, REMAP_KNOTS)
    weights = np.exp(-0.5 * ((v_c[None, :] - knots[:, None]) / (knots[1] - knots[0])) ** 2)
    log_k = (weights @ log_d) / weights.sum(axis=1)
    log_k = np.maximum(log_k - log_k.max(), -math.log(REMAP_MAX_RATIO))
    try:
        remap = Remap(tuple(knots), tuple(np.exp(log_k - 0.5 * log_k.min())))
    except ValueError:
        return None
    rho = remap.total / (total * remap.density(v_c))
    return replace(spec, remap=remap), float((np.sum(e * rho**4) / np.sum(e)) ** 0.25)


def _regraded(prep: Prepared, edges: np.ndarray, diff: np.ndarray, j: int, remap: bool = False) -> Optional[tuple]:
    """``(spec, cell factor)``: the grid family whose logarithmic grading towards the wall (its weight ``c_wall``
    and its inner scale ``wall_depth``) needs the fewest cells for the first level's error, and the ratio of the
    cells it needs to those the old family needs; or None where no candidate saves :data:`REGRADE_GAIN`.

    ``diff``: the first level's Richardson differences ``[zero weight, cells from j on]`` on the N grid ``edges``.
    A cell's error scales with its width to the fourth power, so under a candidate monitor ``Phi'`` the error
    becomes ``sum_i d_i rho_i^4`` with ``rho_i = (Phi'_tot / Phi_tot) (dPhi/dp / dPhi'/dp)(p_i)``, and the cells
    for the same error scale with its fourth root.  The lumped entry is charged with the largest ``rho`` below
    the floor.  Candidates: :data:`REGRADE_FACTORS` on ``c_wall`` times :data:`REGRADE_DEPTHS`.
    """
    spec = prep.spec
    d = np.abs(diff)
    if not np.isfinite(d).all() or d.sum() <= 0.0 or spec.remap is not None:
        return None
    centres_ = 0.5 * (edges[j:-1] + edges[j + 1:])
    below = 0.5 * (edges[:j] + edges[1:j + 1])  # the cells below the floor, lumped into the first entry
    pts = np.concatenate(([centres_[0]], centres_, below))  # the lumped entry at the first cell above the floor
    n_pts = centres_.size + 1
    knots = spec.all_knots
    rest = replace(spec, c_wall=0.0)  # the monitor without its logarithmic grading
    rest_tot = float(rest.phi(knots[-1]) - rest.phi(knots[0]))
    phi_tot = float(spec.phi(knots[-1]) - spec.phi(knots[0]))
    dphi = spec.dphi(pts)
    fractions = (0.0,) + (REGRADE_DEPTHS if spec.p_wall > 0.0 else ())
    deltas = np.array([replace(spec, wall_depth=_wall_depth(spec, k))._delta for k in fractions])
    weights = spec.c_wall * np.array((1.0,) + REGRADE_FACTORS)
    x = pts - spec.p_wall
    span = knots[-1] - spec.p_wall
    tot = rest_tot + weights[:, None] * np.log((span + deltas) / deltas)[None, :]  # (weights, depths)
    cand_dphi = rest.dphi(pts)[None, None, :] + weights[:, None, None] / (x[None, None, :] + deltas[None, :, None])
    rho = (tot / phi_tot)[:, :, None] * dphi[None, None, :] / cand_dphi
    if below.size:
        rho[:, :, 0] = np.maximum(rho[:, :, 0], np.max(rho[:, :, n_pts:], axis=2))
    cost = (np.sum(d * rho[:, :, :n_pts] ** 4, axis=2) / float(np.sum(d))) ** 0.25
    same = (weights == spec.c_wall)[:, None] & (deltas == spec._delta)[None, :]
    cost[same] = np.inf  # the present grading is no candidate
    # no candidate steeper than WALL_GRADING_MAX
    cost[weights > WALL_GRADING_MAX, :] = np.inf
    iw, idp = np.unravel_index(int(np.argmin(cost)), cost.shape)
    best_cost = float(cost[iw, idp])
    if remap:
        remapped = _remapped(spec, edges, diff, j)
        if remapped is not None and remapped[1] < 1.0 - REGRADE_GAIN and remapped[1] < REMAP_PREFERENCE * best_cost:
            return remapped
    if not best_cost < 1.0 - REGRADE_GAIN:
        return None
    return replace(spec, c_wall=float(weights[iw]), wall_depth=_wall_depth(spec, fractions[idp])), best_cost
