"""Subnormal numbers flushed to zero around the compiled stage kernels (x86-64 Linux).

The far tails of a closure (``zeta >= 1`` on the Fig. 1 scene) fall below the
smallest normal double, 2.2e-308, and the tridiagonal eliminations then work on
subnormal numbers, which x86 processors handle in microcode, 10-100x slower
than normal ones.  Measured on this machine (2 cores), 200/400/800 cells, the
Fig. 1 scene at rtol 1e-6: ``local_g1`` at ``zeta = 4`` took 16.9 ms, 11.1 ms
with subnormals flushed; ``local_g1_balanced`` at ``zeta = 1`` 26.4 ms against
17.3 ms; at ``zeta = 0.01`` (no subnormals) nothing changed.  The answers moved
by at most 1.1e-305 in the cdf (numbers below 2.2e-308 become 0).

:func:`flush_subnormals` sets the SSE control register's flush-to-zero (FTZ)
and denormals-are-zero (DAZ) bits for the *calling thread* and restores the
register on exit, so nothing outside the kernel call sees the change.  It works
through glibc's ``fegetenv``/``fesetenv`` (the x86-64 ``fenv_t`` keeps MXCSR at
byte 28 of its 32); elsewhere (other processors or C libraries) it does nothing.
"""
from __future__ import annotations

import contextlib
import ctypes
import platform
import sys
from typing import Iterator, Optional

#: MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6) bits
_FTZ_DAZ = 0x8040
#: glibc x86-64: sizeof(fenv_t) and the offset of its __mxcsr field
_FENV_SIZE = 32
_MXCSR_OFFSET = 28

_LIBM: Optional[ctypes.CDLL] = None
_CHECKED = False


def _libm() -> Optional[ctypes.CDLL]:
    """glibc's libm on x86-64 Linux, else None (then :func:`flush_subnormals` does nothing)."""
    global _LIBM, _CHECKED
    if not _CHECKED:
        _CHECKED = True
        if sys.platform.startswith("linux") and platform.machine().lower() in ("x86_64", "amd64") \
                and platform.libc_ver()[0] == "glibc":
            try:
                try:  # glibc's soname on x86-64 (ctypes.util.find_library runs ldconfig: 14 ms of a first solve)
                    lib = ctypes.CDLL("libm.so.6")
                except OSError:
                    from ctypes.util import find_library

                    lib = ctypes.CDLL(find_library("m") or "libm.so.6")
                lib.fegetenv.argtypes = lib.fesetenv.argtypes = [ctypes.c_void_p]
                lib.fegetenv.restype = lib.fesetenv.restype = ctypes.c_int
                _LIBM = lib
            except (OSError, AttributeError):
                _LIBM = None
    return _LIBM


def available() -> bool:
    """Whether this platform's subnormals can be flushed (x86-64, Linux, glibc)."""
    return _libm() is not None


def mxcsr() -> Optional[int]:
    """The calling thread's MXCSR register (None where :func:`available` is False)."""
    lib = _libm()
    if lib is None:
        return None
    env = ctypes.create_string_buffer(_FENV_SIZE)
    if lib.fegetenv(env) != 0:
        return None
    return int.from_bytes(env.raw[_MXCSR_OFFSET:_MXCSR_OFFSET + 4], "little")


@contextlib.contextmanager
def flush_subnormals(enabled: bool = True) -> Iterator[bool]:
    """Within the block, the calling thread flushes subnormal results and inputs to zero.

    Yields whether the flush is active (False where the platform does not allow
    it, or with ``enabled=False``).  The thread's floating-point environment is
    restored on exit, also on an exception.
    """
    lib = _libm() if enabled else None
    saved = ctypes.create_string_buffer(_FENV_SIZE) if lib is not None else None
    if lib is None or lib.fegetenv(saved) != 0:
        yield False
        return
    raw = bytearray(saved.raw)
    value = int.from_bytes(raw[_MXCSR_OFFSET:_MXCSR_OFFSET + 4], "little") | _FTZ_DAZ
    raw[_MXCSR_OFFSET:_MXCSR_OFFSET + 4] = value.to_bytes(4, "little")
    flushed = ctypes.create_string_buffer(bytes(raw), _FENV_SIZE)
    if lib.fesetenv(flushed) != 0:
        yield False
        return
    try:
        yield True
    finally:
        lib.fesetenv(saved)
