"""The package's compiled kernels called from their stored machine code, without importing numba.

A closure's first solve in a fresh process used to carry numba's whole import: 0.15-0.37 s on this project's
machine, more than the 0.3 s issue 10 allows the first solve, before any kernel ran (docs/performance.md). The
kernels need none of it to *run*. What runs is machine code: numba's cache holds it as an object file per
kernel (``cache=True``), with the kernel's CPython wrapper (argument unboxing, the GIL released for ``nogil``
kernels, the results boxed) compiled into it. This module keeps a second copy of that object code, written the
first time a process loads or compiles a kernel through numba, and links it in later processes with llvmlite's
MCJIT alone (about 50 ms to import and initialize, against numba's 150-370 ms), against the same C helpers
numba links it against: numba's runtime (``_nrt_python``), its helper library (``_helperlib``) and its
function objects (``_dynfunc``), loaded from numba's installation as plain extension modules. The callable is
made exactly as numba makes it (``_dynfunc.make_function`` over the wrapper, with the kernel's environment).
Same object code, same helpers: the same bits (``tests/diffusion_pr/test_machine_code.py``).

These go through numba, as everything did before:

* a kernel not yet stored (the first process after installing, or after an edit of a kernel's source), which
  numba then loads or compiles and this module adds to the store;
* arguments that do not match the kernel's one signature exactly (dtype, dimensions, layout, writeable and
  aligned arrays; Python or numpy floats, integers and booleans where numba's ``typeof`` gives the signature's
  type); numba's dispatcher then decides, as it always did;
* another numba, llvmlite, Python, CPU, ``NUMBA_*`` setting or kernel source (all in the store's key), a store
  that fails to load, or ``DIFFUSION_PR_MACHINE_CODE=0``.

The store lives next to the package's numba cache (``__pycache__/diffusion_pr_kernels-<key>.mc``; under
``NUMBA_CACHE_DIR`` where that is set; in the user's cache folder where the installation cannot be written to),
written atomically; a folder that cannot be written either only means numba loads the kernels. It is a
pickle, trusted as numba trusts its own cache files in the same folder. Linux x86-64 (ELF objects) only;
elsewhere every kernel goes through numba.
"""
from __future__ import annotations

import builtins
import ctypes
import glob
import importlib
import importlib.util
import os
import pickle
import platform
import struct
import sys
import tempfile
import threading
import types as _pytypes
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from ._extensions import extension_file, load_extension

try:  # CPython's own BLAKE2 (hashlib's import loads OpenSSL's bindings: 6-7 ms of a first solve)
    from _blake2 import blake2b as _digest
except ImportError:  # pragma: no cover - another Python
    from hashlib import blake2b as _digest

__all__ = ["kernel", "status", "store_path", "store_folder", "write_atomically", "ENV_MACHINE_CODE", "elf_symbols"]

#: environment variable: ``0`` keeps every kernel on numba (no store read or written)
ENV_MACHINE_CODE = "DIFFUSION_PR_MACHINE_CODE"
#: the store's format (part of its key)
FORMAT = 1
#: the package's kernel modules and the modules whose values they compile in (the store's key hashes their source)
KERNEL_SOURCES = ("_closure_kernels.py", "_closure_rows.py", "solvers/fv/_kernels.py", "solvers/fv/_grid_kernel.py",
                  "solvers/fv/_tail_kernel.py", "solvers/fv/cram.py")

_PACKAGE = Path(__file__).resolve().parent
_LOCK = threading.RLock()
#: ``(module, name) -> callable`` of :func:`kernel`
_KERNELS: dict = {}
_STATE: dict = {"store": None, "loaded": False, "why": "not used yet", "native": [], "numba": []}

_ELF_SYMTAB, _ELF_UNDEF, _ELF_OBJECT, _ELF_FUNC = 2, 0, 1, 2


def elf_symbols(object_code: bytes, undefined: bool = False) -> Optional[set]:
    """The names an ELF64 little-endian object file defines (``undefined`` False) or needs (True); ``None`` for
    another format.

    Defined: symbols with a name, a section (not ``SHN_UNDEF``) and the type ``STT_OBJECT`` or ``STT_FUNC``,
    whatever their binding. Needed: named symbols without a section.
    """
    data = bytes(object_code)
    if len(data) < 64 or data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        return None
    try:
        (shoff,) = struct.unpack_from("<Q", data, 0x28)
        shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
        sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
        names = set()
        for _, kind, _, _, offset, size, link, _, _, entsize in sections:
            if kind != _ELF_SYMTAB or entsize < 24:
                continue
            strings = sections[link][4]
            for j in range(size // entsize):
                name, info, _, shndx, _, _ = struct.unpack_from("<IBBHQQ", data, offset + j * entsize)
                if not name:
                    continue
                if undefined:
                    wanted = shndx == _ELF_UNDEF
                else:
                    wanted = shndx != _ELF_UNDEF and (info & 0xF) in (_ELF_OBJECT, _ELF_FUNC)
                if wanted:
                    start = strings + name
                    names.add(data[start:data.index(b"\0", start)].decode())
        return names
    except (struct.error, IndexError, ValueError, UnicodeDecodeError):
        return None


# --- the store's key and place -----------------------------------------------------------------------------------

def _enabled() -> tuple:
    """``(enabled, why not)``."""
    if os.environ.get(ENV_MACHINE_CODE, "1") == "0":
        return False, f"{ENV_MACHINE_CODE}=0"
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False, "NUMBA_DISABLE_JIT is set (the kernels are plain Python)"
    if not (sys.platform.startswith("linux") and platform.machine().lower() in ("x86_64", "amd64")):
        return False, "stored machine code is used on Linux x86-64 only"
    return True, ""


def _numba_dir() -> Optional[Path]:
    spec = importlib.util.find_spec("numba")
    if spec is None or spec.origin is None:
        return None
    return Path(spec.origin).resolve().parent


_EXTENSIONS = {"nrt": "core/runtime/_nrt_python*.so", "helperlib": "_helperlib*.so", "dynfunc": "_dynfunc*.so"}


def _key(ll) -> str:
    """The store's key: everything the stored machine code depends on."""
    numba_dir = _numba_dir()
    if numba_dir is None:
        raise ImportError("numba is not installed")
    stats = []
    for pattern in _EXTENSIONS.values():
        st = extension_file(numba_dir, pattern).stat()
        stats.append((st.st_size, st.st_mtime_ns))
    dist = sorted(os.path.basename(p) for p in glob.glob(str(numba_dir.parent / "numba-*.dist-info")))
    sources = _digest()
    for rel in KERNEL_SOURCES:
        sources.update((_PACKAGE / rel).read_bytes())
    import llvmlite

    numba_env = sorted((k, v) for k, v in os.environ.items() if k.startswith("NUMBA_") and k != "NUMBA_CACHE_DIR")
    key = repr((FORMAT, sys.version_info[:3], sys.implementation.cache_tag, dist, stats, llvmlite.__version__,
                ll.get_process_triple(), ll.get_host_cpu_name(), ll.get_host_cpu_features().flatten(), numba_env,
                np.__version__, sources.hexdigest()))
    return _digest(key.encode()).hexdigest()[:24]


def store_path(ll=None) -> Optional[Path]:
    """Where this installation's store is (None where stored machine code is not used)."""
    if not _enabled()[0]:
        return None
    ll = ll or _llvm()
    return store_folder() / f"diffusion_pr_kernels-{_key(ll)}.mc"


def store_folder() -> Path:
    """``NUMBA_CACHE_DIR/diffusion_pr`` where that is set; else the package's ``__pycache__`` (next to numba's cache
    of the same kernels) where it can be written; else the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``,
    ``/diffusion_pr``), as numba itself falls back to a user-wide cache for an installation it cannot write to."""
    base = os.environ.get("NUMBA_CACHE_DIR")
    if base:
        return Path(base) / "diffusion_pr"
    inside = _PACKAGE / "__pycache__"
    if os.access(inside if inside.is_dir() else _PACKAGE, os.W_OK):
        return inside
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "diffusion_pr"


def write_atomically(path: Path, obj: Any) -> None:
    """``obj`` pickled to ``path`` through a temporary file in the same folder, so that a process starting at the same
    time reads the old file or the new one, never half of one; readable by all, as numba's cache files. Raises
    ``OSError`` where the folder cannot be written (the callers then keep numba's way)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(obj, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.chmod(tmp, 0o644)  # (mkstemp makes 0600)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _llvm():
    import llvmlite.binding as ll

    ll.initialize_native_target()
    ll.initialize_native_asmprinter()
    return ll


# --- loading ------------------------------------------------------------------------------------------------------

#: numba's C extensions as numba imports them, and the names their init functions have
_NUMBA_MODULES = {"nrt": ("numba.core.runtime._nrt_python", "_nrt_python"),
                  "helperlib": ("numba._helperlib", "_helperlib"), "dynfunc": ("numba._dynfunc", "_dynfunc")}


def _numba_extensions() -> dict:
    """numba's runtime, helper library and function objects: numba's own modules where numba is imported, else the
    same files loaded as modules of their own, set up as numba's import sets them up.

    Loading ``_nrt_python`` initializes numba's memory system (libc's allocator); numba's import then switches it to
    CPython's raw allocator (``numba.core.runtime.nrt``), and so does this load, so that memory allocated before a
    later import of numba is freed by the same allocator after it (numba's import initializes it again, the same
    way). Where numba is imported, its modules are used as they are: a second initialization would reset them.
    """
    if all(name in sys.modules for name, _ in _NUMBA_MODULES.values()):
        return {kind: sys.modules[name] for kind, (name, _) in _NUMBA_MODULES.items()}
    numba_dir = _numba_dir()
    ext = {kind: load_extension(init, extension_file(numba_dir, _EXTENSIONS[kind]))
           for kind, (_, init) in _NUMBA_MODULES.items()}
    ext["nrt"].memsys_use_cpython_allocator()
    if os.environ.get("NUMBA_NRT_STATS", "0") not in ("", "0"):
        ext["nrt"].memsys_enable_stats()
    return ext


#: numba's ``_numba_unpickle`` (``numba.core.serialize``): the wrappers unpickle the constants they box with (the
#: ndarray class), memoized by the address of their bytes
_UNPICKLED: dict = {}
_UNPICKLE_TYPE = ctypes.CFUNCTYPE(ctypes.py_object, ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p)


def _unpickle(address: int, size: int, hashed: int) -> Any:
    key = (address, ctypes.string_at(hashed, 20) if hashed else None)
    try:
        return _UNPICKLED[key]
    except KeyError:
        obj = _UNPICKLED[key] = pickle.loads(ctypes.string_at(address, size))
        return obj


_UNPICKLE = _UNPICKLE_TYPE(_unpickle)


class _Linker:
    """One MCJIT engine holding the stored kernels, with numba's C helpers as its symbols."""

    def __init__(self, ll) -> None:
        self.ll = ll
        self.ext = _numba_extensions()
        target = ll.Target.from_triple(ll.get_process_triple())
        options = dict(cpu=ll.get_host_cpu_name(), features=ll.get_host_cpu_features().flatten(), opt=3,
                       reloc="default", codemodel="jitdefault")
        try:
            self.tm = target.create_target_machine(jit=True, **options)
        except TypeError:  # pragma: no cover - an llvmlite without the jit option
            self.tm = target.create_target_machine(**options)
        self.engine = ll.create_mcjit_compiler(ll.parse_assembly(""), self.tm)
        self.keep: list = []

    def address(self, provider: tuple) -> Optional[int]:
        """The address a stored object's symbol resolves to (numba's table), None: the process's own symbols."""
        kind = provider[0]
        if kind in self.ext:
            return int(self.ext[kind].c_helpers[provider[1]])
        if kind == "none":
            return id(None)
        if kind == "exc":
            return id(getattr(builtins, provider[1]))
        if kind == "unpickle":  # numba's own where numba is imported (its unpickler then imports nothing)
            if "numba.core.serialize" in sys.modules:
                return int(self.ext["helperlib"].c_helpers["unpickle"])
            return ctypes.cast(_UNPICKLE, ctypes.c_void_p).value
        return None

    def link(self, entry: dict) -> Callable:
        """The entry's kernel as numba's own callable (``_dynfunc.make_function`` over its CPython wrapper)."""
        ll = self.ll
        for name, provider in entry["symbols"].items():
            address = self.address(provider)
            if address is not None:
                ll.add_symbol(name, address)
            elif not ll.address_of_symbol(name):
                raise LookupError(f"symbol {name!r} of {entry['qualname']} not found in this process")
        self.engine.add_object_file(ll.ObjectFileRef.from_data(entry["object"]))
        self.engine.finalize_object()
        wrapper = self.engine.get_function_address(entry["wrapper"])
        env_slot = self.engine.get_global_value_address(entry["env"])
        if not wrapper or not env_slot:
            raise LookupError(f"{entry['qualname']}: the stored object does not define its wrapper or environment")
        dynfunc = self.ext["dynfunc"]
        env = dynfunc.Environment({"__name__": entry["module"]})
        env.consts[:] = list(entry["consts"])
        (ctypes.c_void_p * 1).from_address(env_slot)[0] = id(env)
        module = _pytypes.ModuleType(entry["module"])
        function = dynfunc.make_function(module, entry["qualname"].split(".")[-1],
                                         f"compiled wrapper for {entry['qualname']!r} (stored machine code)",
                                         wrapper, env, (self.engine,))
        self.keep.append((env, function))
        return function


# --- argument checks: exactly numba's typeof of the one signature -------------------------------------------------

def _array_check(dtype: str, ndim: int, layout: str) -> Callable[[Any], bool]:
    want = np.dtype(dtype)
    contiguous = layout == "C"

    def check(a) -> bool:
        if type(a) is not np.ndarray or a.dtype != want or a.ndim != ndim:
            return False
        flags = a.flags
        return flags.writeable and flags.aligned and (flags.c_contiguous or not contiguous)
    return check


def _is_float(x) -> bool:
    return type(x) is float or type(x) is np.float64


def _is_int(x) -> bool:
    return type(x) is int or type(x) is np.int64


def _is_bool(x) -> bool:
    return type(x) is bool or type(x) is np.bool_


_SCALAR_CHECKS = {"float64": _is_float, "int64": _is_int, "bool": _is_bool}


def _checks(spec: tuple) -> tuple:
    return tuple(_array_check(*s[1:]) if s[0] == "array" else _SCALAR_CHECKS[s[1]] for s in spec)


class _Stored:
    """A kernel called from the store where its arguments are the signature's, through numba otherwise."""

    __slots__ = ("_function", "_checks", "_fallback", "__name__")

    def __init__(self, function: Callable, spec: tuple, fallback: Callable[[], Callable], name: str) -> None:
        self._function, self._checks, self._fallback = function, _checks(spec), fallback
        self.__name__ = name

    def __call__(self, *args):
        checks = self._checks
        if len(args) == len(checks):
            for check, a in zip(checks, args):
                if not check(a):
                    break
            else:
                return self._function(*args)
        return self._fallback()(*args)


# --- the store ----------------------------------------------------------------------------------------------------

class _Store:
    def __init__(self, ll, path: Path, entries: dict) -> None:
        self.ll, self.path, self.entries = ll, path, entries
        self._linker: Optional[_Linker] = None

    def function(self, module: str, name: str, fallback: Callable[[], Callable]) -> Optional[Callable]:
        entry = self.entries.get((module, name))
        if entry is None:
            return None
        if self._linker is None:
            self._linker = _Linker(self.ll)
        return _Stored(self._linker.link(entry), entry["spec"], fallback, name)


def _open_store() -> Optional[_Store]:
    """This process's store (read once), None where stored machine code is not used; ``_STATE["why"]`` says why."""
    if _STATE["loaded"]:
        return _STATE["store"]
    _STATE["loaded"] = True
    ok, why = _enabled()
    if not ok:
        _STATE["why"] = why
        return None
    try:
        ll = _llvm()
        path = store_path(ll)
    except Exception as exc:  # noqa: BLE001 - the store is an optimization: numba loads the kernels instead
        _STATE["why"] = f"store unavailable: {type(exc).__name__}: {exc}"
        return None
    entries, why = _read_entries(path)
    _STATE["store"], _STATE["why"] = _Store(ll, path, entries), why
    return _STATE["store"]


def _key_of(path: Path) -> str:
    return path.stem.rsplit("-", 1)[1]


def _read_entries(path: Path) -> tuple:
    """``(entries, why)`` of the store at ``path``: none where it is missing, of another format or key, or damaged
    (then rewritten as kernels load through numba)."""
    if not path.exists():
        return {}, f"no store yet at {path}"
    try:
        with open(path, "rb") as fh:
            data = pickle.load(fh)
        if data.get("format") == FORMAT and data.get("key") == _key_of(path):
            return data["entries"], f"{len(data['entries'])} kernels stored in {path}"
        return {}, f"a store of another format or key at {path}: rewritten"
    except Exception as exc:  # noqa: BLE001 - a damaged store: rewritten as kernels load through numba
        return {}, f"damaged store at {path} ({type(exc).__name__}: {exc}): rewritten"


def _spec_of(numba_type) -> Optional[tuple]:
    from numba.core import types as nt

    if isinstance(numba_type, nt.Array):
        if numba_type.layout not in ("C", "A") or not numba_type.mutable or not numba_type.aligned:
            return None
        if numba_type.dtype not in (nt.float64, nt.int64, nt.boolean, nt.complex128):
            return None
        return ("array", str(np.dtype(str(numba_type.dtype) if numba_type.dtype != nt.boolean else "bool")),
                int(numba_type.ndim), numba_type.layout)
    for name, t in (("float64", nt.float64), ("int64", nt.int64), ("bool", nt.boolean)):
        if numba_type == t:
            return ("scalar", name)
    return None


def _providers(undefined: set) -> dict:
    """For each symbol a stored object needs, where numba's table takes it from (in a process that imported numba)."""
    import llvmlite.binding as ll
    from numba import _dynfunc, _helperlib
    from numba.core.runtime import _nrt_python

    tables = {"nrt": _nrt_python.c_helpers, "helperlib": _helperlib.c_helpers, "dynfunc": _dynfunc.c_helpers}
    out = {}
    for name in sorted(undefined):
        provider = ("process",)
        if name == "numba_unpickle":
            provider = ("unpickle",)
        elif name == "_Py_NoneStruct":
            provider = ("none",)
        elif name.startswith("PyExc_") and isinstance(getattr(builtins, name[6:], None), type):
            provider = ("exc", name[6:])
        else:
            address = ll.address_of_symbol(name)
            for kind, table in tables.items():
                for key, value in table.items():
                    if name in (key, "NRT_" + key, "numba_" + key) and int(value) == address:
                        provider = (kind, key)
                        break
                if provider[0] != "process":
                    break
        out[name] = provider
    return out


def _entry(module: str, name: str, dispatcher) -> Optional[dict]:
    """The store's entry for a loaded one-signature numba dispatcher (None where it cannot be stored)."""
    overloads = list(dispatcher.overloads.values())
    if len(overloads) != 1:
        return None
    cres = overloads[0]
    library = cres.library
    code = getattr(library, "_diffusion_pr_object", None) or getattr(library, "_compiled_object", None)
    if not code:
        return None
    spec = tuple(_spec_of(t) for t in cres.signature.args)
    undefined = elf_symbols(code, undefined=True)
    if any(s is None for s in spec) or undefined is None:
        return None
    return {"module": module, "name": name, "qualname": cres.fndesc.qualname, "object": bytes(code),
            "wrapper": cres.fndesc.llvm_cpython_wrapper_name, "env": cres.fndesc.env_name,
            "consts": list(cres.environment.consts), "spec": spec, "symbols": _providers(undefined)}


def _store_entry(module: str, name: str, dispatcher) -> None:
    """Adds the kernel to this installation's store (atomically; nothing where that fails)."""
    store = _STATE["store"]
    if store is None or (module, name) in store.entries:
        return
    try:
        entry = _entry(module, name, dispatcher)
        if entry is None:
            return
        # with what another process may have added meanwhile
        entries = {**store.entries, **_read_entries(store.path)[0], (module, name): entry}
        write_atomically(store.path, {"format": FORMAT, "key": _key_of(store.path), "entries": entries})
        store.entries = {**entries, **store.entries}
    except Exception:  # noqa: BLE001 - an unwritable folder: numba keeps loading this kernel
        pass


def kernel(module: str, name: str) -> Callable:
    """The kernel ``module.name`` (a :class:`~diffusion_pr._numba_load.LoadedBySignature` there) as a callable.

    From the store where it holds the kernel (numba not imported), else numba's dispatcher (loaded or compiled
    for its one signature), which is then added to the store for later processes.
    """
    try:
        return _KERNELS[module, name]
    except KeyError:
        pass
    with _LOCK:
        if (module, name) in _KERNELS:
            return _KERNELS[module, name]

        def through_numba() -> Callable:
            return getattr(importlib.import_module(module), name)()

        store = _open_store()
        function = None
        if store is not None:
            try:
                function = store.function(module, name, through_numba)
            except Exception as exc:  # noqa: BLE001 - a store that does not link: numba loads the kernel
                _STATE["why"] = f"{module}.{name} did not link: {type(exc).__name__}: {exc}"
                function = None
        if function is None:
            function = through_numba()
            _store_entry(module, name, function)
            _STATE["numba"].append(f"{module}.{name}")
        else:
            _STATE["native"].append(f"{module}.{name}")
        _KERNELS[module, name] = function
        return function


def status() -> dict:
    """Which kernels this process took from the store (``native``) and which through numba, and the store's state."""
    return {"store": str(_STATE["store"].path) if _STATE["store"] is not None else None, "why": _STATE["why"],
            "native": list(_STATE["native"]), "numba": list(_STATE["numba"])}
