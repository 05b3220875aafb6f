"""The finite-volume engine every grid backend shares (see :mod:`.engine`)."""
from .engine import DIAGNOSTIC_KEYS, FLOOR, build_result, prepare, solve_fv

__all__ = ["DIAGNOSTIC_KEYS", "FLOOR", "build_result", "prepare", "solve_fv"]
