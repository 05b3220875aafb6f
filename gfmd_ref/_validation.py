"""Small input checks that raise ``ValueError`` naming the parameter, value and allowed range."""
from __future__ import annotations

import math
import numbers

import numpy as np


def check_positive(name: str, value) -> float:
    """A finite float > 0."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}")
    return v


def check_int(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}")
    return int(value)


def check_heights(heights) -> np.ndarray:
    """A finite, square, 2-D float64 array (C-contiguous copy if needed)."""
    try:
        h = np.asarray(heights, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"heights must be a square 2-D array of finite real numbers; got {type(heights).__name__}"
        ) from None
    if h.ndim != 2 or h.shape[0] != h.shape[1]:
        raise ValueError(
            "heights must be a square 2-D array (n, n) describing one L x L periodic cell; "
            f"got shape {h.shape}"
        )
    if h.shape[0] < 2:
        raise ValueError(f"heights must be at least 2 x 2; got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        bad = int(np.size(h) - np.count_nonzero(np.isfinite(h)))
        raise ValueError(f"heights must be finite; got {bad} NaN/inf value(s)")
    return np.ascontiguousarray(h)
