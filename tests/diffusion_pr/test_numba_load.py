"""Cached kernels load without numba's registry refresh (:mod:`diffusion_pr._numba_load`).

Oracles: numba's own load of the same cache (``DIFFUSION_PR_NUMBA_REFRESH=1``) for
the answers, bit for bit; ``sys.modules`` for whether the refresh ran (it imports
``numba.np.linalg``, which nothing on a cached load needs); the dispatchers' cache
statistics for whether the machine code came from the cache.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import diffusion_pr as dp

_CLOSURE_RUN = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    import diffusion_pr as dp
    S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    r = dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, closure="local_g1", rtol=1e-4)
    from diffusion_pr.solvers.fv import _kernels as k
    from diffusion_pr import _closure_kernels as ck
    from numba.core import entrypoints
    print(json.dumps(dict(
        bits=hashlib.sha256(r.weights.tobytes() + r.p.tobytes() + np.float64(r.zero_weight).tobytes()).hexdigest(),
        refreshed="numba.np.linalg" in sys.modules,
        arrayobj="numba.np.arrayobj" in sys.modules,
        entry_points=getattr(entrypoints, "_already_initialized", None),
        signatures=len(k.staged_run_rows.signatures),
        rows_signatures=len(ck._model_rows.signatures),
        cache_hits=sum(k.staged_run_rows.stats.cache_hits.values()),
        success=bool(r.success))))
""")


def _numba_supported() -> bool:
    """The numba cache internals :mod:`diffusion_pr._numba_load` relies on are there (else it leaves numba alone)."""
    from numba.core.caching import FunctionCache

    return all(hasattr(FunctionCache, n) for n in ("_load_overload", "_guard_against_spurious_io_errors"))


needs_internals = pytest.mark.skipif(not _numba_supported(),
                                     reason="this numba's cache internals differ: the package keeps numba's own load")


def _run(code: str, env_extra: dict, cwd=None, args=()) -> dict:
    # numba's load is what these tests measure: not the kernels' stored machine code (diffusion_pr._machine_code)
    env = {**os.environ, "DIFFUSION_PR_MACHINE_CODE": "0", **env_extra}
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True, env=env,
                         cwd=cwd)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def warm_closure_cache():
    """The kernels compiled into numba's on-disk cache before the fresh processes load them: by a solve that goes
    through numba (not the stored machine code), and the staged and row kernels loaded in this process too."""
    from diffusion_pr import _closure_kernels as ck
    from diffusion_pr.solvers.fv import _kernels as k

    assert _run(_CLOSURE_RUN, {})["success"]
    k.staged_run_rows_kernel()
    ck._rows_kernel()


@needs_internals
def test_closure_in_a_fresh_process_loads_without_refresh_same_bits(warm_closure_cache):
    """A fresh process's closure solve loads the cached kernels without the refresh and gets the bits of numba's
    own load; ``staged_run_rows`` has exactly one specialization although the solve passes both a single grid's
    contiguous rows and a group's column views, and both kernels are loaded by signature (numba's extension entry
    points are not initialized)."""
    fast = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0"})
    numba_own = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "1"})
    assert fast["success"] and numba_own["success"]
    assert fast["bits"] == numba_own["bits"]
    assert fast["cache_hits"] >= 1 and numba_own["cache_hits"] >= 1  # both loaded machine code, neither compiled
    assert not fast["refreshed"]
    assert numba_own["refreshed"]  # the oracle's load is numba's, refresh included
    assert fast["signatures"] == 1 and numba_own["signatures"] == 1
    assert fast["rows_signatures"] == 1 and numba_own["rows_signatures"] == 1
    # both kernels loaded by their signatures: numba's argument dispatch (``_compile_for_args``) never ran, nor the
    # scan of the installed distributions for numba extensions that it starts (0-17 ms of a first closure call,
    # measured in alternating fresh processes)
    if fast["entry_points"] is not None:
        assert fast["entry_points"] is False


_TINY = textwrap.dedent("""
    from numba import njit
    from diffusion_pr._numba_load import load_without_refresh

    @njit(cache=True)
    def twice(x):
        return 2 * x

    SWITCHED = load_without_refresh(globals())
""")

_TINY_RUN = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, ".")
    import tiny_kernels as t
    a = t.twice(1.5)
    loaded = sum(t.twice.stats.cache_hits.values())
    refreshed_after_load = "numba.np.linalg" in sys.modules
    b = t.twice(int(sys.argv[1]))  # the warm run's first int: compiled by numba's compiler (it refreshes itself)
    print(json.dumps(dict(a=a, b=b, switched=t.SWITCHED, loaded=loaded, refreshed_after_load=refreshed_after_load,
                          refreshed_after_compile="numba.np.linalg" in sys.modules)))
""")


@needs_internals
def test_load_without_refresh_compiles_on_a_miss_and_loads_on_a_hit(tmp_path):
    """Cold cache: the function compiles (numba's compiler refreshes); warm cache: it loads without the refresh;
    a new signature after such a load still compiles and is right."""
    (tmp_path / "tiny_kernels.py").write_text(_TINY)
    env = {"DIFFUSION_PR_NUMBA_REFRESH": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    cold = _run(_TINY_RUN.replace("int(sys.argv[1])", "1.0"), env, cwd=tmp_path)  # float only: one signature
    warm = _run(_TINY_RUN, env, cwd=tmp_path, args=("2",))
    assert (cold["a"], cold["b"], cold["switched"]) == (3.0, 2.0, 1)
    assert (warm["a"], warm["b"], warm["switched"]) == (3.0, 4, 1)
    assert warm["refreshed_after_compile"]
    assert cold["loaded"] == 0 and cold["refreshed_after_load"]  # compiled: the compiler refreshed
    assert warm["loaded"] == 1 and not warm["refreshed_after_load"]  # loaded: no refresh


@needs_internals
def test_opt_out_keeps_numba_cache(monkeypatch):
    """``DIFFUSION_PR_NUMBA_REFRESH=1`` leaves a module's dispatchers with numba's own cache class."""
    from numba import njit
    from numba.core.caching import FunctionCache

    from diffusion_pr._numba_load import ENV_KEEP_REFRESH, load_without_refresh

    def make():
        @njit(cache=False)
        def f(x):  # pragma: no cover - numba
            return x

        f.enable_caching()
        return {"f": f}

    monkeypatch.setenv(ENV_KEEP_REFRESH, "1")
    ns = make()
    assert load_without_refresh(ns) == 0 and type(ns["f"]._cache) is FunctionCache
    monkeypatch.setenv(ENV_KEEP_REFRESH, "0")
    assert load_without_refresh(ns) == 1 and type(ns["f"]._cache) is not FunctionCache
    assert load_without_refresh(ns) == 0  # switched once only


_WARMED_RUN = textwrap.dedent("""
    import json, sys
    import numpy as np
    import diffusion_pr as dp
    from diffusion_pr.solvers import warm_up
    from diffusion_pr.solvers.fv import _kernels as k
    from diffusion_pr import _closure_kernels as ck
    warm_up("native")
    loads = lambda: sum(k.staged_run_rows.stats.cache_hits.values()) + sum(ck._model_rows.stats.cache_hits.values())
    before = loads()
    S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    r = dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=0.25, closure="local_g1_balanced",
                                 rtol=1e-4)
    print(json.dumps(dict(before=before, after=loads(), success=bool(r.success))))
""")


def test_warm_up_loads_every_kernel_a_closure_solve_needs(warm_closure_cache):
    """After ``warm_up("native")`` a closure solve loads no further machine code: the warm-up's own loads are the
    coefficient rows' and the staged kernel's (one each)."""
    out = _run(_WARMED_RUN, {})
    assert out["success"]
    assert out["before"] == 2 and out["after"] == 2


# --- the shared bitcode parsed only when linked (``_unserialize_lazily``) ---------------------------------------

def _lazy_supported() -> bool:
    from diffusion_pr._numba_load import _lazy_link_enabled

    return _numba_supported() and _lazy_link_enabled()


needs_lazy = pytest.mark.skipif(not _lazy_supported(), reason="numba's library internals differ: numba's own "
                                                              "unserialization runs")


def test_elf_symbols_are_the_bitcode_symbols_numba_lists(warm_closure_cache):
    """Oracle: numba's own list of a library's defined symbols, from its shared bitcode (``_load_defined_symbols``:
    functions and global variables that are not declarations). The object file's symbol table gives the same names
    for every overload of the package's staged and row kernels (the entry points among them)."""
    from llvmlite import binding as ll

    from diffusion_pr import _closure_kernels as ck
    from diffusion_pr._numba_load import elf_defined_symbols
    from diffusion_pr.solvers.fv import _kernels as k

    checked = 0
    for kernel in (k.staged_run_rows, ck._model_rows):
        codegen = kernel.targetctx.codegen()
        for sig in kernel.signatures:
            # what the on-disk cache holds for this overload (a loaded library's object code is consumed by the load)
            payload = kernel._cache._cache_file.load(kernel._cache._index_key(sig, codegen))
            name, kind, (object_code, bitcode) = payload[0]
            assert kind == "object"
            module = ll.parse_bitcode(bitcode)
            numba_list = {gv.name for group in (module.functions, module.global_variables) for gv in group
                          if not gv.is_declaration}
            elf = elf_defined_symbols(object_code)
            if elf is None:  # pragma: no cover - not an ELF64 platform
                pytest.skip("object files are not ELF64 here: numba's own unserialization runs")
            assert elf == numba_list
            assert kernel.overloads[sig].fndesc.llvm_func_name in elf  # the entry point numba asks the engine for
            checked += 1
    assert checked >= 2
    assert elf_defined_symbols(b"\x7fELF" + b"\x01" * 60) is None  # 32-bit: not read
    assert elf_defined_symbols(b"not an object file" * 4) is None


_TINY_LINK = textwrap.dedent("""
    from numba import njit
    from diffusion_pr._numba_load import load_without_refresh

    @njit(cache=True)
    def twice(x):
        return 2.0 * x

    load_without_refresh(globals())

    @njit(cache=False)
    def four_times(x):  # compiled in every process: links the cached ``twice`` into itself
        return twice(twice(x))
""")

_TINY_LINK_RUN = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, ".")
    import tiny_link as t
    a = t.twice(1.5)
    lib = t.twice.overloads[t.twice.signatures[0]].library
    lazy_before = "_lazy_shared_bitcode" in vars(lib)
    b = t.four_times(1.25)
    print(json.dumps(dict(a=a, b=b, loaded=sum(t.twice.stats.cache_hits.values()), lazy_before=lazy_before,
                          parsed_after="_lazy_shared_bitcode" not in vars(lib) and lib._shared_module is not None)))
""")


@needs_lazy
def test_lazily_loaded_library_links_into_a_later_compile(tmp_path):
    """A cached kernel loaded without its bitcode, then linked into a function compiled afterwards: the bitcode is
    parsed at that link and the caller is right (oracle: arithmetic). Without the lazy parse numba's linking of an
    object-code library fails ("library unfit for linking")."""
    (tmp_path / "tiny_link.py").write_text(_TINY_LINK)
    env = {"DIFFUSION_PR_NUMBA_REFRESH": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    cold = _run(_TINY_LINK_RUN, env, cwd=tmp_path)
    warm = _run(_TINY_LINK_RUN, env, cwd=tmp_path)
    assert (cold["a"], cold["b"], cold["loaded"]) == (3.0, 5.0, 0)  # compiled: nothing lazy
    assert not cold["lazy_before"]
    assert (warm["a"], warm["b"], warm["loaded"]) == (3.0, 5.0, 1)
    assert warm["lazy_before"] and warm["parsed_after"]


@needs_lazy
def test_lazy_link_gives_the_bits_of_numba_unserialization(warm_closure_cache):
    """Oracle: the same fresh-process closure solve with numba's own unserialization (``..._LAZY_LINK=0``)."""
    lazy = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_LAZY_LINK": "1"})
    own = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_LAZY_LINK": "0"})
    assert lazy["success"] and own["success"] and lazy["cache_hits"] >= 1
    assert lazy["bits"] == own["bits"]


# --- numba's runtime functions, cached (``initialize_runtime``) ----------------------------------------------------

_NRT_RUN = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, ".")
    import numpy as np
    import tiny_link as t
    from numba import njit
    from numba.core.runtime import rtsys
    a = t.twice(1.5)  # a cached load: initializes the runtime
    loaded_runtime = getattr(rtsys.library, "_compiled_object", 0) is None  # unserialized: consumed by the load

    @njit
    def fresh(n):  # compiled after that: links the runtime, allocates and returns an array (reference counts)
        out = np.empty(n)
        for i in range(n):
            out[i] = t.twice(i)
        return out

    b = fresh(4)
    print(json.dumps(dict(a=a, b=b.tolist(), loaded_runtime=loaded_runtime)))
""")


@needs_lazy
def test_runtime_machine_code_is_cached_and_links_into_later_compiles(tmp_path):
    """First process: the runtime compiled (numba's way) and written; second: loaded from that file, and a function
    compiled afterwards allocates and returns an array through it (oracle: arithmetic). A corrupt file is ignored
    and rewritten."""
    (tmp_path / "tiny_link.py").write_text(_TINY_LINK)
    env = {"DIFFUSION_PR_NUMBA_REFRESH": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    first = _run(_NRT_RUN, env, cwd=tmp_path)
    files = list((tmp_path / "cache" / "diffusion_pr").glob("numba_nrt-*.nbo"))
    assert len(files) == 1
    second = _run(_NRT_RUN, env, cwd=tmp_path)
    for out in (first, second):
        assert out["a"] == 3.0 and out["b"] == [0.0, 2.0, 4.0, 6.0]
    assert not first["loaded_runtime"] and second["loaded_runtime"]
    files[0].write_bytes(b"not a pickle")
    third = _run(_NRT_RUN, env, cwd=tmp_path)
    assert not third["loaded_runtime"] and third["b"] == [0.0, 2.0, 4.0, 6.0]
    fourth = _run(_NRT_RUN, env, cwd=tmp_path)
    assert fourth["loaded_runtime"]
    off = _run(_NRT_RUN, {**env, "DIFFUSION_PR_NUMBA_NRT_CACHE": "0"}, cwd=tmp_path)
    assert not off["loaded_runtime"] and off["b"] == [0.0, 2.0, 4.0, 6.0]


@needs_lazy
def test_cached_runtime_gives_the_bits_of_numba_runtime(warm_closure_cache):
    """Oracle: the same fresh-process closure solve with numba compiling its runtime (``..._NRT_CACHE=0``)."""
    _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_NRT_CACHE": "1"})  # file written
    cached = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_NRT_CACHE": "1"})
    own = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_NRT_CACHE": "0"})
    assert cached["success"] and own["success"]
    assert cached["bits"] == own["bits"]


@needs_lazy
def test_environments_rebuilt_without_importing_numba_modules(warm_closure_cache):
    """Oracle: the same fresh-process closure solve with numba's rebuild of the environments (``..._LAZY_ENV=0``),
    which imports ``numba.np.arrayobj`` for ``np.empty``'s environment: the same bits, and the lazy rebuild leaves
    that module unimported."""
    lazy = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_LAZY_ENV": "1"})
    own = _run(_CLOSURE_RUN, {"DIFFUSION_PR_NUMBA_REFRESH": "0", "DIFFUSION_PR_NUMBA_LAZY_ENV": "0"})
    assert lazy["success"] and own["success"] and lazy["cache_hits"] >= 1
    assert lazy["bits"] == own["bits"]
    assert own["arrayobj"] and not lazy["arrayobj"]


def test_lazy_environment_keeps_numba_semantics_for_other_modules():
    """An environment already in numba's memo is returned as it is; a module that is imported, or not numba's, is
    rebuilt numba's way (its real globals); a numba module not yet imported gets ``{"__name__": modname}``."""
    from numba.core import environment as E

    from diffusion_pr._numba_load import _rebuild_env_lazily

    own = _rebuild_env_lazily("json", [1, "a"], "test-env-json")  # imported or not: not numba's, numba's way
    assert own.globals is sys.modules["json"].__dict__ and list(own.consts) == [1, "a"]
    assert _rebuild_env_lazily("json", [], "test-env-json") is own  # from the memo
    imported = _rebuild_env_lazily("numba.core.types", [], "test-env-types")  # numba's, imported: numba's way
    assert imported.globals is sys.modules["numba.core.types"].__dict__
    name = "numba.not_a_module_for_this_test"
    lazy = _rebuild_env_lazily(name, [2.5], "test-env-lazy")
    assert lazy.globals == {"__name__": name} and list(lazy.consts) == [2.5] and lazy.env_name == "test-env-lazy"
    assert E.lookup_environment("test-env-lazy") is lazy
    assert name not in sys.modules


@needs_lazy
def test_runtime_cache_in_an_unwritable_place_leaves_numba_behaviour(tmp_path):
    """Where the runtime's file cannot be written (here its folder's name is taken by a file), every process
    compiles the runtime as numba does, and the answers are right (oracle: arithmetic); no temporary file is left."""
    (tmp_path / "tiny_link.py").write_text(_TINY_LINK)
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "diffusion_pr").write_text("a file where the folder would be")
    env = {"DIFFUSION_PR_NUMBA_REFRESH": "0", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    for _ in range(2):
        out = _run(_NRT_RUN, env, cwd=tmp_path)
        assert out["a"] == 3.0 and out["b"] == [0.0, 2.0, 4.0, 6.0] and not out["loaded_runtime"]
    assert not list((tmp_path / "cache").glob("*.tmp"))
