"""Wall interactions (Müser 2008, Eq. 7; docs/gfmd.md)."""
from __future__ import annotations

from dataclasses import dataclass

from ._validation import check_positive

__all__ = ["HardWall", "ExponentialRepulsion"]


@dataclass(frozen=True)
class HardWall:
    """Non-overlap: ``gap >= 0``, ``pressure >= 0``, ``pressure * gap = 0``."""


@dataclass(frozen=True)
class ExponentialRepulsion:
    """Exponential repulsion ``V[g] = v0 integral exp(-g/zeta)`` (paper Eq. 7).

    The local pressure is ``sigma = (v0/zeta) exp(-g/zeta)``. ``v0`` only shifts the
    mean separation ``z0``; the solvers fix it to ``v0 = zeta * p0`` so that
    ``sigma = p0 exp(-g/zeta)``: the gap is zero where the local pressure equals the
    mean pressure. ``zeta -> 0`` is the hard wall.
    """

    zeta: float

    def __post_init__(self):
        object.__setattr__(self, "zeta", check_positive("zeta", self.zeta))
