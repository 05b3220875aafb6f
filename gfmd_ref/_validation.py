"""Small input checks that raise ``ValueError`` naming the parameter, value and allowed range."""
from __future__ import annotations

import math
import numbers
import os
import tempfile

import numpy as np


def check_real(name: str, value, *, low: float | None = None, high: float | None = None) -> float:
    """A finite real number (not a string or bool), optionally within ``[low, high]``."""
    rng = f" in [{low!r}, {high!r}]" if low is not None and high is not None else (
        f" >= {low!r}" if low is not None else (f" <= {high!r}" if high is not None else ""))
    v = float(value) if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) else math.nan
    if not math.isfinite(v) or (low is not None and v < low) or (high is not None and v > high):
        raise ValueError(f"{name} must be a finite real number{rng}; got {name}={value!r}")
    return v


def check_positive(name: str, value) -> float:
    """A finite float > 0 (strings and bools are rejected, not parsed)."""
    try:
        v = math.nan if isinstance(value, (str, bytes, bool, np.bool_)) else float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}")
    return v


def check_int(name: str, value, minimum: int = 1) -> int:
    """An integer (not a bool or float) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}")
    return int(value)


def check_heights(heights) -> np.ndarray:
    """A finite 2-D float64 array of at least 2 x 2 points, one periodic cell (rows and
    columns may differ; a C-contiguous copy if needed)."""
    try:
        h = np.asarray(heights, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"heights must be a 2-D array of finite real numbers; got {type(heights).__name__}") from None
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(
            f"heights must be a 2-D array (rows, columns), each >= 2, of one periodic cell; got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"heights must be finite; got {int(np.size(h) - np.count_nonzero(np.isfinite(h)))} "
                         "NaN/inf value(s)")
    return np.ascontiguousarray(h)


#: a map is periodic when its largest jump across the cell boundary is at most this
#: multiple of its largest step between neighbours inside (per axis).
PERIODIC_JUMP_LIMIT = 3.0


def check_periodic(h: np.ndarray) -> None:
    """Refuse a height map that is not one periodic cell.

    The solvers treat ``heights`` as one period of an infinite surface, so the last
    row (column) is a neighbour of the first. Rule, per axis: the largest jump across
    that boundary must not exceed :data:`PERIODIC_JUMP_LIMIT` times the largest step
    between neighbours inside the map (a tilted plane of ``n`` points has a ratio
    ``n - 1``; a periodic random surface about 1).
    """
    for axis, name in ((0, "first (rows)"), (1, "second (columns)")):
        inside = float(np.max(np.abs(np.diff(h, axis=axis))))
        jump = float(np.max(np.abs(np.take(h, 0, axis=axis) - np.take(h, -1, axis=axis))))
        if jump > PERIODIC_JUMP_LIMIT * inside:
            raise ValueError(
                f"heights is not periodic along its {name} axis: the jump across the boundary ({jump:.3g}) "
                f"is {jump / inside if inside > 0 else float('inf'):.3g} times the largest step inside "
                f"({inside:.3g}; allowed: <= {PERIODIC_JUMP_LIMIT:g}). Prepare measured data as one periodic "
                "cell: remove the mean plane (detrend) and multiply by a window that goes to zero at the edges "
                "(e.g. numpy.hanning along each axis), or pad it with zeros to twice its size; or pass "
                "check_periodic=False to solve it as it is")


#: the meaningful range of a solver tolerance (relative to p0): a residual of 10 % of
#: p0 is already the coarsest answer worth calling converged.
TOL_MAX = 0.1


def check_tol(tol) -> float:
    """A residual tolerance in ``(0, TOL_MAX]`` (relative to the mean pressure)."""
    if isinstance(tol, (bool, np.bool_)) or not isinstance(tol, numbers.Real) or not 0 < float(tol) <= TOL_MAX:
        raise ValueError(f"tol must be a number in (0, {TOL_MAX:g}] (relative to the mean pressure p0); "
                         f"got tol={tol!r}")
    return float(tol)


def check_seed(name: str, value):
    """An integer >= 0 or a :class:`numpy.random.SeedSequence` (what ``default_rng`` accepts reproducibly)."""
    if isinstance(value, np.random.SeedSequence):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0 or a numpy SeedSequence; got {name}={value!r}")
    return int(value)


def check_writable_dir(name: str, path) -> str:
    """Create the folder ``path`` if needed and check that a file can be written in it:
    called before any expensive work, so an unwritable output folder is an immediate
    ``ValueError`` naming the parameter, not a crash after the solve."""
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
