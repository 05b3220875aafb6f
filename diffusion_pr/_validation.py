"""Shared input checks for :mod:`diffusion_pr`.

Every check raises :class:`ValueError` (for a wrong kind of object its subclass :class:`InputTypeError`, also a
:class:`TypeError`) whose message names the parameter, shows the offending value and states the allowed range, e.g.
``ValueError: variance must be > 0 and finite; got -1.0``.  Scalars come back as ``float``, arrays as float arrays."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["InputTypeError", "check_positive", "check_nonnegative", "check_finite", "check_finite_array",
           "check_in_range", "check_callable", "check_int", "check_seed", "check_writable"]


class InputTypeError(TypeError, ValueError):
    """Wrong kind of input (not a number, not callable, ...): both a ``TypeError`` and a ``ValueError``."""


def _as_float(name: str, value: Any) -> float | np.ndarray:
    """Convert ``value`` to float (scalar) or float array; reject non-numbers and complex numbers."""
    def refuse() -> InputTypeError:
        shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:76] + " ..."
        return InputTypeError(f"{name} must be a real number or array of real numbers; got {shown}")

    if isinstance(value, (str, bytes, complex)) or value is None or np.iscomplexobj(value):
        raise refuse()
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise refuse() from exc
    return float(arr) if arr.ndim == 0 else arr


def _show(value: float | np.ndarray, bad: np.ndarray | None = None) -> str:
    """Short representation of an offending value for error messages."""
    if np.ndim(value) == 0:
        return repr(float(value))
    arr = np.asarray(value)
    if bad is not None and np.any(bad):
        return f"array of shape {arr.shape} with offending entries {arr[bad].ravel()[:3].tolist()}"
    return f"array of shape {arr.shape}"


def _check(name: str, value: ArrayLike, ok: Callable[[np.ndarray], np.ndarray], want: str) -> float | np.ndarray:
    """``value`` as float / float array if ``ok`` holds for every entry, else ``ValueError: <name> must <want>``."""
    v = _as_float(name, value)
    bad = ~ok(np.asarray(v))
    if np.any(bad):
        raise ValueError(f"{name} must {want}; got {_show(v, bad if np.ndim(v) else None)}")
    return v


def check_finite(name: str, value: ArrayLike) -> float | np.ndarray:
    """``value`` (scalar or array) as float, required finite (no NaN, no inf)."""
    return _check(name, value, np.isfinite, "be finite")


def check_positive(name: str, value: ArrayLike) -> float | np.ndarray:
    """``value`` (scalar or every array entry) as float, required finite and > 0."""
    return _check(name, value, lambda v: np.isfinite(v) & (v > 0), "be > 0 and finite")


def check_nonnegative(name: str, value: ArrayLike) -> float | np.ndarray:
    """``value`` (scalar or every array entry) as float, required finite and >= 0."""
    return _check(name, value, lambda v: np.isfinite(v) & (v >= 0), "be >= 0 and finite")


def check_finite_array(name: str, arr: ArrayLike, *, ndim: int | None = None,
                       shape: tuple[int | None, ...] | None = None, min_size: int = 1) -> np.ndarray:
    """``arr`` as a finite real float array with ``ndim`` dimensions, of ``shape`` (``None`` entries match any
    length) and at least ``min_size`` elements, each where given; the errors name ``name``."""
    a = np.asarray(_as_float(name, arr), dtype=float)
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array; got shape {a.shape}")
    if shape is not None and (a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape))):
        want = tuple("any" if s is None else s for s in shape)
        raise ValueError(f"{name} must have shape {want}; got shape {a.shape}")
    if a.size < min_size:
        raise ValueError(f"{name} must have at least {min_size} element(s); got {a.size}")
    n_bad = int(np.count_nonzero(~np.isfinite(a)))
    if n_bad:
        raise ValueError(f"{name} must be finite (no NaN or inf); got {n_bad} non-finite "
                         f"entr{'y' if n_bad == 1 else 'ies'} in an array of shape {a.shape}")
    return a


def check_in_range(name: str, value: ArrayLike, lo: float, hi: float, *, lo_inclusive: bool = True,
                   hi_inclusive: bool = True) -> float | np.ndarray:
    """``value`` (scalar or every array entry) as float, required in ``[lo, hi]`` (NaN rejected); ``lo_inclusive``,
    ``hi_inclusive`` say whether the bounds are allowed; ``-inf`` / ``inf`` for one-sided ranges."""
    def ok(v: np.ndarray) -> np.ndarray:
        return (v >= lo if lo_inclusive else v > lo) & (v <= hi if hi_inclusive else v < hi) & ~np.isnan(v)

    interval = f"{'[' if lo_inclusive else '('}{lo}, {hi}{']' if hi_inclusive else ')'}"
    return _check(name, value, ok, f"lie in {interval}")


def check_callable(name: str, obj: Any) -> Callable[..., Any]:
    """``obj``, required callable (else :class:`InputTypeError` naming ``name``)."""
    if not callable(obj):
        raise InputTypeError(f"{name} must be callable (a vectorized function of p); got {obj!r} of type "
                             f"{type(obj).__name__}")
    return obj


def check_int(name: str, value: Any, minimum: int = 1) -> int:
    """Require an integer (not a bool or float) >= ``minimum``; return it as ``int``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {name}={value!r}")
    return int(value)


def check_seed(name: str, value: Any) -> Any:
    """Require an integer >= 0 or a :class:`numpy.random.SeedSequence` (what ``default_rng`` takes reproducibly)."""
    if isinstance(value, np.random.SeedSequence):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0 or a numpy SeedSequence; got {name}={value!r}")
    return int(value)


def check_writable(name: str, path: Any, *, folder: bool = True) -> str:
    """``path`` as a string once a file can be written there: a folder (created if needed) or, with
    ``folder=False``, a file (its folder must exist; the file is left as it was).  Called before any expensive
    work, so an unwritable output is an immediate ``ValueError`` naming the parameter."""
    import os
    import tempfile

    try:
        target = os.fspath(path)
    except TypeError:
        raise ValueError(f"{name} must be a path; got {name}={path!r}") from None
    try:
        if folder:
            os.makedirs(target, exist_ok=True)
            tempfile.TemporaryFile(dir=target).close()
        elif os.path.isdir(target):
            raise IsADirectoryError(21, "a folder")
        else:
            existed = os.path.exists(target)
            open(target, "a").close()
            if not existed:
                os.remove(target)
    except OSError as exc:
        raise ValueError(f"{name}={target!r} is not a writable {'folder' if folder else 'file'}: "
                         f"{exc.strerror or exc}") from None
    return target
