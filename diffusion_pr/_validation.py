"""Shared input checks for :mod:`diffusion_pr`.

Every helper raises :class:`ValueError` (for a wrong kind of object its
subclass :class:`InputTypeError`, which is also a :class:`TypeError`) whose
message names the parameter, shows the offending value and states the allowed
range, e.g.::

    ValueError: variance must be > 0 and finite; got -1.0

Scalars are returned as ``float``; array-likes are returned as a float
``numpy.ndarray`` so callers can use the checked value directly. These are
internal helpers (leading underscore module), but other modules of the package
import them, so their signatures are stable.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "InputTypeError",
    "check_positive",
    "check_nonnegative",
    "check_finite",
    "check_finite_array",
    "check_in_range",
    "check_callable",
    "check_int",
    "check_seed",
    "check_writable_dir",
]


class InputTypeError(TypeError, ValueError):
    """Wrong kind of input (not a number, not callable, ...).

    Subclasses both :class:`TypeError` and :class:`ValueError`, so callers and
    tests may catch either; every check in this module therefore raises a
    ``ValueError`` in the broad sense.
    """


def _as_float(name: str, value: Any) -> float | np.ndarray:
    """Convert ``value`` to float (scalar) or float array; reject non-numbers."""
    if isinstance(value, (str, bytes)) or value is None:
        raise InputTypeError(f"{name} must be a real number; got {value!r}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputTypeError(f"{name} must be a real number or array of real numbers; got {value!r}") from exc
    if arr.ndim == 0:
        return float(arr)
    return arr


def _show(value: float | np.ndarray, bad: np.ndarray | None = None) -> str:
    """Short representation of an offending value for error messages."""
    if np.ndim(value) == 0:
        return repr(float(value))
    arr = np.asarray(value)
    if bad is not None and np.any(bad):
        first = arr[bad].ravel()[:3]
        return f"array of shape {arr.shape} with offending entries {first.tolist()}"
    return f"array of shape {arr.shape}"


def check_finite(name: str, value: ArrayLike) -> float | np.ndarray:
    """Require ``value`` (scalar or array) to be finite (no NaN, no inf).

    Parameters
    ----------
    name : str
        Parameter name used in the error message.
    value : float or array_like
        Value to check.

    Returns
    -------
    float or numpy.ndarray
        ``value`` as float / float array.

    Raises
    ------
    ValueError
        If any entry is NaN or infinite.
    """
    v = _as_float(name, value)
    bad = ~np.isfinite(v)
    if np.any(bad):
        raise ValueError(f"{name} must be finite; got {_show(v, np.atleast_1d(bad) if np.ndim(v) else None)}")
    return v


def check_positive(name: str, value: ArrayLike) -> float | np.ndarray:
    """Require ``value`` (scalar or every array entry) to be finite and > 0.

    Returns the value as float (scalar) or float array; raises ``ValueError``
    with the parameter name, the value and the allowed range otherwise.
    """
    v = _as_float(name, value)
    bad = ~(np.isfinite(v) & (np.asarray(v) > 0))
    if np.any(bad):
        raise ValueError(f"{name} must be > 0 and finite; got {_show(v, bad if np.ndim(v) else None)}")
    return v


def check_nonnegative(name: str, value: ArrayLike) -> float | np.ndarray:
    """Require ``value`` (scalar or every array entry) to be finite and >= 0.

    Returns the value as float (scalar) or float array; raises ``ValueError``
    with the parameter name, the value and the allowed range otherwise.
    """
    v = _as_float(name, value)
    bad = ~(np.isfinite(v) & (np.asarray(v) >= 0))
    if np.any(bad):
        raise ValueError(f"{name} must be >= 0 and finite; got {_show(v, bad if np.ndim(v) else None)}")
    return v


def check_finite_array(
    name: str,
    arr: ArrayLike,
    *,
    ndim: int | None = None,
    shape: tuple[int | None, ...] | None = None,
    min_size: int = 1,
) -> np.ndarray:
    """Require ``arr`` to be a finite real float array of the expected shape.

    Parameters
    ----------
    name : str
        Parameter name used in the error message.
    arr : array_like
        Values to check.
    ndim : int, optional
        Required number of dimensions.
    shape : tuple of int or None, optional
        Required shape; ``None`` entries match any length.
    min_size : int, default 1
        Minimum number of elements.

    Returns
    -------
    numpy.ndarray
        ``arr`` as a float array (a copy only if conversion was needed).

    Raises
    ------
    ValueError
        On NaN/inf entries, a wrong number of dimensions, wrong shape or too
        few elements.
    """
    if np.iscomplexobj(arr):
        raise ValueError(f"{name} must be real-valued; got a complex array")
    a = np.asarray(_as_float(name, arr), dtype=float)
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array; got shape {a.shape}")
    if shape is not None:
        if a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape)):
            want = tuple("any" if s is None else s for s in shape)
            raise ValueError(f"{name} must have shape {want}; got shape {a.shape}")
    if a.size < min_size:
        raise ValueError(f"{name} must have at least {min_size} element(s); got {a.size}")
    bad = ~np.isfinite(a)
    if np.any(bad):
        raise ValueError(
            f"{name} must be finite (no NaN or inf); got {int(bad.sum())} non-finite entr"
            f"{'y' if bad.sum() == 1 else 'ies'} in an array of shape {a.shape}"
        )
    return a


def check_in_range(
    name: str,
    value: ArrayLike,
    lo: float,
    hi: float,
    *,
    lo_inclusive: bool = True,
    hi_inclusive: bool = True,
) -> float | np.ndarray:
    """Require ``lo <(=) value <(=) hi`` for a scalar or every array entry.

    Parameters
    ----------
    name : str
        Parameter name used in the error message.
    value : float or array_like
        Value to check (NaN is always rejected).
    lo, hi : float
        Bounds; use ``-inf``/``inf`` for one-sided ranges.
    lo_inclusive, hi_inclusive : bool, default True
        Whether the bounds themselves are allowed.

    Returns
    -------
    float or numpy.ndarray
        The checked value as float / float array.
    """
    v = _as_float(name, value)
    va = np.asarray(v)
    ok_lo = va >= lo if lo_inclusive else va > lo
    ok_hi = va <= hi if hi_inclusive else va < hi
    bad = ~(ok_lo & ok_hi) | np.isnan(va)
    if np.any(bad):
        left = "[" if lo_inclusive else "("
        right = "]" if hi_inclusive else ")"
        raise ValueError(
            f"{name} must lie in {left}{lo}, {hi}{right}; got {_show(v, bad if np.ndim(v) else None)}"
        )
    return v


def check_callable(name: str, obj: Any) -> Callable[..., Any]:
    """Require ``obj`` to be callable.

    Raises
    ------
    InputTypeError
        (a ``ValueError`` and a ``TypeError``) naming ``name`` if ``obj`` is
        not callable.
    """
    if not callable(obj):
        raise InputTypeError(f"{name} must be callable (a vectorized function of p); got {obj!r} of type {type(obj).__name__}")
    return obj


def check_int(name: str, value: Any, minimum: int = 1) -> int:
    """Require an integer (not a bool or float) >= ``minimum``; return it as ``int``."""
    import numbers

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}")
    return int(value)


def check_seed(name: str, value: Any) -> Any:
    """Require an integer >= 0 or a :class:`numpy.random.SeedSequence` (what ``default_rng`` accepts
    reproducibly)."""
    import numbers

    if isinstance(value, np.random.SeedSequence):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0 or a numpy SeedSequence; got {name}={value!r}")
    return int(value)


def check_writable_dir(name: str, path: Any) -> str:
    """Create the folder ``path`` if needed and check that a file can be written in it (before any expensive
    work, so an unwritable output folder is an immediate ``ValueError`` naming the parameter)."""
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
