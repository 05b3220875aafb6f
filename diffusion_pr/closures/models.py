r"""The shell closures' coefficients and their staged problem (:func:`closure_problem`).

Shell ``k`` diffuses with ``f_k(p) = g(q_k; p)^2`` (:class:`LocalResponseDiffusivity`, ``g`` the response factor
at the local pressure, :func:`~diffusion_pr.closures.shells.local_response`); the balanced closures add the drift
``b_k`` (:class:`LoadExcessDrift`) and the balance ``w`` (:class:`RigidApproachBalance`) whose multiplier keeps
``<p> = p0``.  The rows of many shells are evaluated in one compiled pass
(:func:`diffusion_pr.closures._kernels.model_rows`).

Units: pressures in the unit of ``E_star``; ``kz = zeta E*/2`` [pressure x length].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .._validation import check_nonnegative, check_positive
from .shells import BALANCED, Shells

__all__ = ["LocalResponseDiffusivity", "LoadExcessDrift", "RigidApproachBalance", "closure_problem",
           "BALANCED_FLOOR"]

#: floor of the balanced closure's non-contact region, relative to zeta q_min E*/2 (docs/closures.md)
BALANCED_FLOOR = 1e-16


def _common_kz(items: tuple) -> Optional[float]:
    """The ``kz > 0`` that all ``items`` share (their rows vectorize), else None.  The formulas clamp ``p`` at
    0."""
    kz = {it.kz for it in items}
    if len(kz) != 1 or kz == {0.0}:
        return None
    return kz.pop()


def _products(kz: float, items: tuple, name: str) -> np.ndarray:
    """``kz x [item.<name> for item in items]``: the shells' wall products ``kz q`` [pressure]."""
    return kz * np.array([getattr(it, name) for it in items], dtype=float)


class _RowPlan:
    """The rows of one shell model for a fixed set of shells, made once per problem and evaluated on many grids.

    ``plan(p, out=None)`` writes the rows at the pressures ``p`` (1-D, clamped at 0; a NaN stays NaN) into ``out``
    (a C-contiguous float array of shape ``(shells, p.size)``; a new one where None or of another layout) in one
    compiled pass (:func:`diffusion_pr.closures._kernels.model_rows`) and returns it, or None where a value is not
    finite (the caller then takes its checked path, which says where).
    """

    __slots__ = ("kq", "kq_part", "model")

    def __init__(self, kq: np.ndarray, kq_part: np.ndarray, model: int) -> None:
        self.kq, self.kq_part, self.model = kq, kq_part, int(model)

    def __len__(self) -> int:
        return int(self.kq.size)

    def __call__(self, p: np.ndarray, out: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        from ._kernels import model_rows

        p = np.ascontiguousarray(p, dtype=float).reshape(-1)
        shape = (self.kq.size, p.size)
        target = out if (out is not None and out.shape == shape and out.dtype == np.float64
                         and out.flags.c_contiguous) else np.empty(shape)
        if not model_rows(self.kq, self.kq_part, p, self.model, target):
            return None
        if out is not None and target is not out:
            out[...] = target
            return out
        return target


class _ShellModel:
    """A shell model of ``p``: the constant ``_HARD_WALL`` for ``kz = 0``, else the compiled formula ``_MODEL`` of
    :mod:`diffusion_pr.closures._kernels` (``p`` clamped at 0) on the wall products ``kz x _PRODUCTS``, evaluated
    row-wise for many shells at once."""

    _HARD_WALL = 0.0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        if self.kz == 0.0:
            return np.full_like(p, self._HARD_WALL)
        from ._kernels import model_rows

        plan = type(self).row_plan((self,))
        out = np.empty((1, p.size))
        model_rows(plan.kq, plan.kq_part, np.ascontiguousarray(p).reshape(-1), plan.model, out)
        return out[0].reshape(p.shape)

    @classmethod
    def row_plan(cls, items: tuple) -> Optional[_RowPlan]:
        """The rows of ``items`` as a reusable :class:`_RowPlan`, or None where they do not share one ``kz > 0``."""
        kz = _common_kz(items)
        if kz is None:
            return None
        return _RowPlan(_products(kz, items, cls._PRODUCTS[0]), _products(kz, items, cls._PRODUCTS[1]), cls._MODEL)


class _LoadModel(_ShellModel):
    """A drift-type shell model: 0 on the hard wall.

    Model protocol (:mod:`diffusion_pr.models`): linear at ``p -> 0`` (``zero_power`` 1), smooth (no breakpoints).
    """

    zero_power = 1.0

    def breakpoints(self) -> tuple[float, ...]:
        return ()


@dataclass(frozen=True)
class LocalResponseDiffusivity(_ShellModel):
    """``f_k(p) = g(q_k; p)^2`` (dimensionless): the diffusivity of shell ``k``.

    ``zero_power`` (:mod:`diffusion_pr.models`) is 2 for ``zeta > 0`` (the wall is never reached, ``ln p``
    diffuses) and 0 for the hard wall (``f = 1``: absorbing ``p = 0``, Persson).

    Parameters
    ----------
    q : float
        Shell wavenumber ``q_k`` [rad/length].
    kz : float
        ``zeta E*/2`` [pressure x length]; 0 for the hard wall.
    """

    q: float
    kz: float

    _HARD_WALL = 1.0  # f = 1: Persson
    _MODEL = 0  # _kernels.DIFFUSIVITY: g(q_k)^2
    _PRODUCTS = ("q", "q")

    @property
    def zero_power(self) -> float:
        return 2.0 if self.kz > 0.0 else 0.0

    def breakpoints(self) -> tuple[float, ...]:
        return ()


@dataclass(frozen=True)
class LoadExcessDrift(_LoadModel):
    """``b_k(p) = (1 - g(q_part; p)) g(q_k; p)^2 / p`` [pressure per unit tau].

    The local load excess of the exponential response, removed in the fraction
    ``1 - g(q_part; p)`` (``q_part = q_min``).  Tends to 0 as ``p -> 0``
    (``~ 4 p/(kz q_k)^2``) and as ``zeta -> 0``.
    """

    q: float
    q_part: float
    kz: float

    _MODEL = 1  # _kernels.DRIFT
    _PRODUCTS = ("q", "q_part")


@dataclass(frozen=True)
class RigidApproachBalance(_LoadModel):
    """``w(p) = (1 - g(q_part; p)) p`` [pressure per unit tau per unit A]: the rigid-body
    approach ``z0`` that restores the load, acting in the fraction ``1 - g(q_part; p)``."""

    q_part: float
    kz: float

    _MODEL = 2  # _kernels.BALANCE
    _PRODUCTS = ("q_part", "q_part")


def closure_problem(shells: Shells, *, zeta: float, E_star: float, mean_pressure: float, closure: str,
                    partition_q: Optional[float] = None) -> Any:
    """The shell-by-shell closure as a :class:`~diffusion_pr.problem.StagedProblem`.

    One :class:`~diffusion_pr.problem.Stage` per shell ``k`` (duration ``dV0_k/2``, pressure^2) with
    ``f_k = g(q_k; p)^2``; for the balanced closures also ``b_k = (1 - g(q_part; p)) g(q_k; p)^2/p`` and the
    balance ``w = (1 - g(q_part; p)) p`` (total drift ``b_k - A w``, ``A`` keeping ``<p> = p0``).  At the hard wall
    every stage holds the same ``f = 1``, which the engine integrates as one exponential.

    Parameters
    ----------
    shells : Shells
        From :func:`spectrum_shells`.
    zeta : float
        Wall range [length], >= 0.
    E_star, mean_pressure : float
        ``E*`` and ``p0`` [pressure], > 0.
    closure : {"local_g1", "local_g1_balanced", "local_g1_shell_balanced"}
    partition_q : float or "shell", optional
        Wavenumber of the partition factor (default ``shells.q_min``; ``"shell"`` takes each shell's own ``q_k``,
        which breaks the ``zeta -> 0`` limit).
    """
    from ..problem import Stage, StagedProblem

    if closure not in ("local_g1", *BALANCED):
        raise ValueError("closure_problem builds 'local_g1', 'local_g1_balanced' or 'local_g1_shell_balanced'; "
                         f"got closure={closure!r}")
    if closure == "local_g1_shell_balanced":
        if partition_q is not None:
            raise ValueError("partition_q is fixed ('shell') for closure='local_g1_shell_balanced'")
        partition_q = "shell"
    kz = 0.5 * float(check_nonnegative("zeta", zeta)) * float(check_positive("E_star", E_star))
    stages = []
    # the hard wall: one diffusivity object for all shells, so the engine integrates them as one exponential
    hard = LocalResponseDiffusivity(float(shells.q_min), 0.0) if kz == 0.0 else None
    # a partition at one wavenumber: one balance object shared by every shell
    shared = None
    if closure != "local_g1" and kz > 0.0 and partition_q != "shell":
        shared = RigidApproachBalance(shells.q_min if partition_q is None else float(partition_q), kz)
    for q, dv in zip(shells.q.tolist(), shells.dV0.tolist()):
        f = hard if hard is not None else LocalResponseDiffusivity(q, kz)
        if closure == "local_g1" or kz == 0.0:
            stages.append(Stage(0.5 * dv, f))
        elif shared is not None:
            stages.append(Stage(0.5 * dv, f, LoadExcessDrift(q, shared.q_part, kz), shared))
        else:
            stages.append(Stage(0.5 * dv, f, LoadExcessDrift(q, q, kz), RigidApproachBalance(q, kz)))
    return StagedProblem(float(check_positive("mean_pressure", mean_pressure)), tuple(stages), label=closure,
                         balance_per_stage=True)

