"""Small input checks that raise ``ValueError`` naming the parameter, value and allowed range."""
from __future__ import annotations

import math
import numbers

import numpy as np


def check_positive(name: str, value) -> float:
    """A finite float > 0 (strings and bools are rejected, not parsed)."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}")
    return v


def check_int(name: str, value, minimum: int = 1) -> int:
    """An integer (not a bool or float) >= ``minimum``."""
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


def check_real(name: str, value, *, low: float | None = None, high: float | None = None) -> float:
    """A finite real number (not a string or bool), optionally within ``[low, high]``."""
    rng = f" in [{low!r}, {high!r}]" if low is not None and high is not None else (
        f" >= {low!r}" if low is not None else (f" <= {high!r}" if high is not None else ""))
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a finite real number{rng}; got {name}={value!r}")
    v = float(value)
    if not math.isfinite(v) or (low is not None and v < low) or (high is not None and v > high):
        raise ValueError(f"{name} must be a finite real number{rng}; got {name}={value!r}")
    return v


def check_seed(name: str, value):
    """An integer >= 0 or a :class:`numpy.random.SeedSequence` (what ``default_rng`` accepts reproducibly)."""
    if isinstance(value, np.random.SeedSequence):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0 or a numpy SeedSequence; got {name}={value!r}")
    return int(value)


def check_writable_dir(name: str, path) -> str:
    """Create the folder ``path`` if needed and check that a file can be written in it.

    Called before any expensive work, so an unwritable output folder is an
    immediate ``ValueError`` naming the parameter, not a crash after the solve.
    """
    import os
    import tempfile

    try:
        folder = os.fspath(path)
    except TypeError:
        raise ValueError(f"{name} must be a path; got {name}={path!r}") from None
    try:
        os.makedirs(folder, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise ValueError(f"{name}={folder!r} is not a writable folder: {exc.strerror or exc}") from None
    return folder
