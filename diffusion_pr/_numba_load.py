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

**The shared bitcode, parsed only when it is linked.** A cached overload holds
its machine code (an object file) and the LLVM bitcode of the same functions,
which numba keeps to link them into *other* functions it compiles later. Numba
parses that bitcode on every load, to list the functions the library defines
(the execution engine answers an entry point's address only for a name on that
list). For the staged kernel (325 kB of machine code, 635 kB of bitcode) the
parse and the list take 31 ms of a 75 ms load, and nothing on a load links the
library into anything. :func:`_unserialize_lazily` takes the list from the
object file's own symbol table instead (an ELF64 file: 0.5 ms) and parses the
bitcode only if numba asks for the library's module to link it
(``_get_module_for_linking``). On all 281 cached overloads of this package the
two lists are the same names (``tests/diffusion_pr/test_numba_load.py``).
Where the object file is not ELF64 little-endian (macOS, Windows) or numba's
library internals differ, numba's own unserialization runs.
``DIFFUSION_PR_NUMBA_LAZY_LINK=0`` keeps numba's (to compare the two).

**The runtime's machine code, cached.** Numba builds and optimizes the LLVM
module of its runtime functions (``NRT_incref``, ``NRT_decref``, the atomic
counters; ``nrtdynmod.compile_nrt_functions``) in every process before its
first load: 55-63 ms when nothing else has set up LLVM yet, about 19 ms of a
closure's first solve. :func:`initialize_runtime` runs numba's
``rtsys.initialize`` with that one step replaced: the first process compiles
the module as numba does and writes its object code next to the package's
numba cache (``__pycache__/numba_nrt-<key>.nbo``, or under
``NUMBA_CACHE_DIR``), keyed by the numba and llvmlite versions, the CPU and
features (``codegen.magic_tuple()``, as numba keys its own cache) and the
runtime's debug switches; later processes load it with numba's own
unserialization (3-4 ms). A file that does not define the runtime's functions is
ignored and the module compiled; an unwritable folder leaves numba's behaviour.
``DIFFUSION_PR_NUMBA_NRT_CACHE=0`` keeps numba's.

**Environments without their modules' imports.** Unpickling a cached overload
rebuilds the environment of every function it calls, numba's own
implementations among them, and numba imports each one's module to do so: 22
numba modules for the staged kernel (``numba.np.arrayobj``, ``numba.np.npyimpl``,
...), though only object-mode code reads an environment's globals.
:func:`_rebuild_env_lazily` gives those environments a one-entry globals dict
instead, for ``numba.*`` modules not yet imported; about 33 ms of a first
solve. ``DIFFUSION_PR_NUMBA_LAZY_ENV=0`` keeps numba's.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import sys
import threading
from pathlib import Path
from typing import Callable, Optional

from numba.core import codegen as _codegen
from numba.core import environment as _environment
from numba.core.caching import FunctionCache
from numba.core.registry import CPUDispatcher
from numba.core.runtime import rtsys

from ._machine_code import elf_symbols, store_folder, write_atomically

__all__ = ["load_without_refresh", "ENV_KEEP_REFRESH", "ENV_LAZY_LINK", "ENV_NRT_CACHE", "ENV_LAZY_ENV",
           "LoadOnlyFunctionCache", "LoadedBySignature", "elf_defined_symbols", "initialize_runtime"]

#: environment variable that keeps numba's own cache load (refresh included) when set to ``1``
ENV_KEEP_REFRESH = "DIFFUSION_PR_NUMBA_REFRESH"
#: environment variable that keeps numba's own unserialization (the shared bitcode parsed on every load) when ``0``
ENV_LAZY_LINK = "DIFFUSION_PR_NUMBA_LAZY_LINK"

#: environment variable that rebuilds the environments of numba's own functions numba's way (importing their modules)
ENV_LAZY_ENV = "DIFFUSION_PR_NUMBA_LAZY_ENV"
#: environment variable that compiles numba's runtime functions in every process (numba's way) when ``0``
ENV_NRT_CACHE = "DIFFUSION_PR_NUMBA_NRT_CACHE"

#: the internals of numba's cache the load relies on
_INTERNALS = ("_load_overload", "_guard_against_spurious_io_errors")
#: the internals of numba's code library the lazy unserialization relies on
_LIBRARY_INTERNALS = ("enable_object_caching", "_set_compiled_object", "_finalize_final_module",
                      "_get_module_for_linking", "_unserialize")



def elf_defined_symbols(object_code: bytes) -> Optional[set]:
    """The names of the data objects and functions an ELF64 little-endian object file defines; ``None`` otherwise.

    Symbols with a name, a section (not ``SHN_UNDEF``) and the type ``STT_OBJECT`` or ``STT_FUNC``, whatever
    their binding: for numba's cached libraries this is the set numba builds from the library's bitcode (its
    functions and global variables that are not declarations).
    """
    return elf_symbols(object_code)


_LAZY_CLASSES: dict = {}


def _lazily_linked_class(cls: type) -> type:
    """``cls`` (numba's code library class) whose shared module is parsed from its bitcode when first linked."""
    lazy = _LAZY_CLASSES.get(cls)
    if lazy is None:
        def _get_module_for_linking(self):
            bitcode = self.__dict__.pop("_lazy_shared_bitcode", None)
            if bitcode is not None and self._shared_module is None:
                from llvmlite import binding as ll

                self._shared_module = ll.parse_bitcode(bitcode)
            return cls._get_module_for_linking(self)

        lazy = type(cls.__name__, (cls,), {"_get_module_for_linking": _get_module_for_linking,
                                           "__module__": __name__})
        _LAZY_CLASSES[cls] = lazy
    return lazy


def _unserialize_lazily(codegen, state):
    """Numba's ``CPUCodeLibrary._unserialize`` for an object-code library, with its shared bitcode kept unparsed.

    The steps are numba's (``numba/core/codegen.py``, 0.61-0.68) but for the shared module, which
    :func:`_lazily_linked_class` parses on the first link, and the list of defined symbols, which comes from the
    object file (:func:`elf_defined_symbols`). Anything else (bitcode libraries, another object format) goes to
    numba's own unserialization.
    """
    name, kind, data = state
    names = elf_defined_symbols(data[0]) if kind == "object" else None
    engine = getattr(codegen, "_engine", None)
    if not names or not isinstance(getattr(engine, "_defined_symbols", None), set):
        return codegen._library_class._unserialize(codegen, state)
    object_code, shared_bitcode = data
    library = codegen.create_library(name)
    library.__class__ = _lazily_linked_class(type(library))
    library._lazy_shared_bitcode = shared_bitcode
    library.enable_object_caching()
    library._set_compiled_object(object_code)
    library._finalize_final_module()
    engine._defined_symbols |= names
    library._diffusion_pr_object = object_code  # for the package's store of machine code (diffusion_pr._machine_code)
    return library


def _lazy_link_enabled() -> bool:
    return (os.environ.get(ENV_LAZY_LINK, "1") != "0"
            and all(hasattr(_codegen.CPUCodeLibrary, n) for n in _LIBRARY_INTERNALS))


_LAZY_LOCK = threading.RLock()


class LoadOnlyFunctionCache(FunctionCache):
    """``FunctionCache`` whose load initializes the NRT instead of refreshing the whole target context.

    The NRT's machine code comes from the package's cache (:func:`initialize_runtime`, unless
    ``DIFFUSION_PR_NUMBA_NRT_CACHE=0``); for the load itself, numba's unserialization is shadowed by
    :func:`_unserialize_lazily` (the shared bitcode parsed when first linked; unless
    ``DIFFUSION_PR_NUMBA_LAZY_LINK=0``) and numba's rebuild of environments by :func:`_rebuild_env_lazily` (no
    imports of numba modules; unless ``DIFFUSION_PR_NUMBA_LAZY_ENV=0``). A loaded overload whose entry points have
    no address is loaded again numba's way.
    """

    def load_overload(self, sig, target_context):
        initialize_runtime(target_context)
        with self._guard_against_spurious_io_errors():
            lazy_link, lazy_env = _lazy_link_enabled(), _lazy_env_enabled()
            if not (lazy_link or lazy_env):
                return self._load_overload(sig, target_context)
            codegen = target_context.codegen()
            with _LAZY_LOCK, contextlib.ExitStack() as shadows:  # numba's functions shadowed for this load only
                if lazy_link:
                    shadows.enter_context(_shadowed(codegen, "unserialize_library",
                                                    lambda state: _unserialize_lazily(codegen, state)))
                if lazy_env:
                    shadows.enter_context(_shadowed(_environment, "_rebuild_env", _rebuild_env_lazily))
                loaded = self._load_overload(sig, target_context)
            if loaded is not None and not _entry_points_defined(loaded):  # never a null entry point: numba's load
                return self._load_overload(sig, target_context)
            return loaded


@contextlib.contextmanager
def _shadowed(owner, name: str, value):
    """``owner.name = value`` inside the block; afterwards the instance attribute is gone or the old value back."""
    own = vars(owner)
    had, old = name in own, own.get(name)
    setattr(owner, name, value)
    try:
        yield
    finally:
        if had:
            setattr(owner, name, old)
        else:
            delattr(owner, name)


_own_rebuild_env = getattr(_environment, "_rebuild_env", None)


def _rebuild_env_lazily(modname, consts, env_name):
    """Numba's ``_rebuild_env`` without importing a numba module that is not imported yet.

    A cached overload carries the environments of every function it calls, numba's own implementations among them
    (``np.empty``'s in ``numba.np.arrayobj``, broadcasting's in ``numba.np.npyimpl``, complex arithmetic's in
    ``numba.cpython.numbers``). Numba rebuilds each one around its module's globals, importing the module: 22
    modules for the staged kernel. An environment's globals are read only by object-mode code, which numba's own
    implementations never are; their constants are restored as numba does. So for a ``numba.*`` module that is not
    imported the environment gets ``{"__name__": modname}`` (which keeps it cachable and picklable); any other
    module, and any imported one, goes through numba's own function.
    """
    env = _environment.lookup_environment(env_name)
    if env is not None:
        return env
    if modname in sys.modules or not str(modname).startswith("numba."):
        return _own_rebuild_env(modname, consts, env_name)
    env = _environment.Environment({"__name__": modname})
    env.consts[:] = consts
    env.env_name = env_name
    _environment.Environment._memo[env_name] = env
    return env


def _lazy_env_enabled() -> bool:
    return (os.environ.get(ENV_LAZY_ENV, "1") != "0" and _own_rebuild_env is not None
            and hasattr(_environment, "lookup_environment") and hasattr(_environment.Environment, "_memo"))


def _entry_points_defined(compile_result) -> bool:
    """Both entry points of a loaded overload (the function and its CPython wrapper) have addresses."""
    fndesc, library = getattr(compile_result, "fndesc", None), getattr(compile_result, "library", None)
    if fndesc is None or library is None:
        return True  # not a compile result: nothing to check
    return all(library.get_pointer_to_function(n) for n in (fndesc.llvm_func_name, fndesc.llvm_cpython_wrapper_name))


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


# --- numba's runtime functions (NRT), cached ---------------------------------------------------------------------

#: the runtime functions numba compiles on its first load or compile in a process (``nrtdynmod.create_nrt_module``)
_NRT_REQUIRED = ("NRT_incref", "NRT_decref", "NRT_MemInfo_data_fast", "nrt_atomic_add", "nrt_atomic_sub")


def _nrt_cache_file(codegen) -> Optional[Path]:
    """Where the runtime's machine code is kept: next to the package's own numba cache, keyed like numba's index."""
    try:
        import llvmlite
        import numba
        from numba.core import config

        key = repr((numba.__version__, llvmlite.__version__, codegen.magic_tuple(), bool(config.NRT_STATS),
                    bool(config.DEBUG_NRT), sys.version_info[:2]))
    except Exception:  # pragma: no cover - another numba: no cache
        return None
    digest = hashlib.sha256(key.encode()).hexdigest()[:20]
    return store_folder() / f"numba_nrt-{digest}.nbo"


def _compile_nrt_functions_cached(ctx):
    """``nrtdynmod.compile_nrt_functions`` with the machine code kept on disk and loaded by later processes."""
    from numba.core.runtime import nrtdynmod

    codegen = ctx.codegen()
    path = _nrt_cache_file(codegen)
    if path is not None:
        try:
            state = pickle.loads(path.read_bytes())
            names = elf_defined_symbols(state[2][0]) if state[1] == "object" else None
            if names is not None and all(n in names for n in _NRT_REQUIRED):
                return codegen.unserialize_library(state)  # numba's own: the runtime is linked into new compiles
        except (OSError, pickle.UnpicklingError, EOFError, IndexError, TypeError, ValueError, AttributeError):
            pass
    ir_module, library = nrtdynmod.create_nrt_module(ctx)
    library.add_ir_module(ir_module)
    library.enable_object_caching()
    library.finalize()
    if path is not None:
        _write_atomically(path, library)
    return library


def _write_atomically(path: Path, library) -> None:
    """The library's serialized state written to ``path`` through a temporary file in the same folder (so that a
    process starting at the same time reads the old file or the new one, never half of one); nothing where the
    folder is not writable (then the runtime is compiled in every process, as numba does)."""
    try:
        write_atomically(path, library.serialize_using_object_code())
    except (OSError, RuntimeError, ValueError):
        pass


def initialize_runtime(target_context) -> None:
    """``rtsys.initialize`` with the runtime's machine code loaded from disk (compiled and kept on the first run).

    Numba builds and optimizes the runtime's LLVM module in every process (55-63 ms alone here, about 18 ms of a
    closure's first solve). Its steps are kept; only
    ``nrtdynmod.compile_nrt_functions`` is replaced, for this one call. ``DIFFUSION_PR_NUMBA_NRT_CACHE=0`` keeps
    numba's.
    """
    from numba.core.runtime import nrtdynmod

    if getattr(rtsys, "_init", False) is True:
        return
    if (os.environ.get(ENV_NRT_CACHE, "1") == "0" or not hasattr(rtsys, "_init")
            or not hasattr(nrtdynmod, "create_nrt_module")):
        rtsys.initialize(target_context)
        return
    with _LAZY_LOCK, _shadowed(nrtdynmod, "compile_nrt_functions", _compile_nrt_functions_cached):
        rtsys.initialize(target_context)  # (returns at once where another thread initialized it meanwhile)
