"""Load the package's cached numba kernels without numba's compiler set-up.

Numba's on-disk cache (``cache=True``) stores machine code. Before it loads a
cached overload, numba refreshes its target context
(``numba.core.base.BaseContext.refresh``): it imports and registers every
lowering implementation it has (``numba.np.linalg``, ``numba.np.arraymath``,
the typed containers, the random generators, ...). On this project's machine
that refresh alone is 0.1-0.24 s of a closure's first call in a fresh process,
and it is only needed to *compile*: unpickling and linking cached machine code
reads none of those registries. The only part a load needs is the NRT runtime
(``rtsys.initialize``), whose symbols the kernels' allocations link against.

:func:`load_without_refresh` switches the caches of the given dispatchers (ours
only; a user's own numba functions keep numba's behaviour) to a load that
initializes the NRT and skips the refresh. A cache miss still compiles through
numba's compiler, which refreshes the context itself
(``numba.core.compiler.CompilerBase.__init__``), so a cold cache or a new
signature behaves exactly as before. The machine code is the same object code
either way: the answers are the same bits (``tests/diffusion_pr/test_numba_load.py``).

It relies on two internals of numba's cache (``FunctionCache`` and its
``_load_overload``), checked when it is applied: where they differ (another numba
version) it leaves the dispatchers as they are. Set the environment variable
``DIFFUSION_PR_NUMBA_REFRESH=1`` to keep numba's own load (for instance to
compare the two).
"""
from __future__ import annotations

import os
import threading
from typing import Callable

from numba.core.caching import FunctionCache
from numba.core.registry import CPUDispatcher
from numba.core.runtime import rtsys

__all__ = ["load_without_refresh", "ENV_KEEP_REFRESH", "LoadOnlyFunctionCache", "LoadedBySignature"]

#: environment variable that keeps numba's own cache load (refresh included) when set to ``1``
ENV_KEEP_REFRESH = "DIFFUSION_PR_NUMBA_REFRESH"

#: the internals of numba's cache the load relies on
_INTERNALS = ("_load_overload", "_guard_against_spurious_io_errors")


class LoadOnlyFunctionCache(FunctionCache):
    """``FunctionCache`` whose load initializes the NRT instead of refreshing the whole target context."""

    def load_overload(self, sig, target_context):
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)


def load_without_refresh(namespace: dict) -> int:
    """Give every cached numba dispatcher in ``namespace`` (a module's ``globals()``) the load without refresh.

    Returns the number of dispatchers switched (0 where ``DIFFUSION_PR_NUMBA_REFRESH=1``
    or where numba's cache internals are not the ones this was written for).
    """
    if os.environ.get(ENV_KEEP_REFRESH, "0") == "1" or not all(hasattr(FunctionCache, n) for n in _INTERNALS):
        return 0
    switched = 0
    for obj in list(namespace.values()):
        cache = getattr(obj, "_cache", None) if isinstance(obj, CPUDispatcher) else None
        if type(cache) is FunctionCache:  # exactly numba's: never a cache class we do not know
            cache.__class__ = LoadOnlyFunctionCache
            switched += 1
    return switched


class LoadedBySignature:
    """A numba dispatcher whose machine code is loaded for one signature on first use; calling the object returns it.

    ``LoadedBySignature(kernel, types, close=False)``: ``kernel.compile(types())`` runs once (a cache load; a
    compile on a miss), so that no call goes through numba's argument dispatch (``_compile_for_args``), which
    types every argument and also scans the installed distributions for numba extensions
    (``entrypoints.init_all``) that a cached load never needs. ``close``: no other signature compiles afterwards
    (``disable_compile``). Under ``NUMBA_DISABLE_JIT`` the kernel is a plain function and is returned as it is.
    The lock: two threads may both get here first, and numba's ``compile`` raises once the other thread has
    disabled compiling.
    """

    __slots__ = ("_kernel", "_types", "_close", "_lock", "_loaded")

    def __init__(self, kernel, types: Callable[[], tuple], close: bool = False) -> None:
        self._kernel, self._types, self._close = kernel, types, bool(close)
        self._lock = threading.Lock()
        self._loaded = False

    def __call__(self):
        if not self._loaded:
            with self._lock:
                if not self._loaded:
                    kernel = self._kernel
                    if hasattr(kernel, "disable_compile"):  # a dispatcher, not a plain function
                        kernel.compile(self._types())
                        if self._close:
                            kernel.disable_compile()
                    self._loaded = True
        return self._kernel
