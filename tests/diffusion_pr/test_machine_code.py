"""The kernels' stored machine code (diffusion_pr._machine_code): numba's bits without numba's import.

Oracles: the same solves through numba's dispatchers (``DIFFUSION_PR_MACHINE_CODE=0``) in another fresh process,
bit for bit; the argument checks against numba's own ``typeof`` of the kernels' signatures.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from diffusion_pr import _machine_code as mc

pytestmark = pytest.mark.skipif(not mc._enabled()[0], reason=f"stored machine code not used here: {mc._enabled()[1]}")

#: every closure at a wall of each regime (far tails at 4; uniform shells at 0.25; graded shells at 0.01): between
#: them and warm_up(), every kernel a closure uses
CHILD = r"""
import hashlib, json, sys
import numpy as np
import diffusion_pr as dp
from diffusion_pr import _machine_code as mc
S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
out = {}
for closure in ("local_g1", "local_g1_balanced", "local_g1_shell_balanced"):
    for zeta in (4.0, 0.25, 0.01):
        r = dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=closure, rtol=1e-6)
        out[f"{closure} {zeta}"] = hashlib.sha256(r.density.tobytes() + r.edges.tobytes()
                                                  + np.float64(r.zero_weight).tobytes()
                                                  + np.float64(r.error_estimate).tobytes()).hexdigest()
from diffusion_pr.solvers import warm_up
warm_up("native")
st = mc.status()
print(json.dumps(dict(answers=out, numba="numba" in sys.modules, native=st["native"], through_numba=st["numba"])))
"""


def _run(setting: str) -> dict:
    env = {**os.environ, mc.ENV_MACHINE_CODE: setting}
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_stored_kernels_give_numbas_bits_without_importing_numba():
    """A fresh process solves nine closure scenes from the store without importing numba, and its answers are the
    bits of the same solves through numba's dispatchers in another fresh process.  The first process adds to the
    store whatever it lacks (the first run after installing or after an edit of a kernel), so the second one must
    take every kernel from it."""
    _run("1")  # the store complete for these scenes
    stored, through_numba = _run("1"), _run("0")
    assert stored["through_numba"] == [] and not stored["numba"]
    assert {k.rsplit(".", 1)[1] for k in stored["native"]} >= {"staged_run_rows_kernel", "_rows_kernel",
                                                                "remap_both_kernel", "remap_inverse_kernel",
                                                                "monitor_newton_kernel", "envelope_kernel",
                                                                "moments_kernel"}
    assert through_numba["native"] == [] and through_numba["numba"]
    assert stored["answers"] == through_numba["answers"]


SPEC = (("array", "float64", 1, "C"), ("array", "float64", 2, "A"), ("array", "bool", 1, "C"),
        ("scalar", "float64"), ("scalar", "int64"), ("scalar", "bool"))


def _good():
    return [np.zeros(3), np.zeros((2, 3)), np.zeros(3, dtype=np.bool_), 1.5, 2, True]


@pytest.mark.parametrize("position, bad", [
    (0, np.zeros(3, dtype=np.float32)),   # another dtype
    (0, np.zeros(6)[::2]),                 # 'C' layout wanted, a strided view given
    (0, np.zeros((1, 3))),                 # another number of dimensions
    (0, [0.0, 0.0, 0.0]),                  # not an array
    (1, np.zeros((2, 3), dtype=np.int64)),
    (2, np.zeros(3)),
    (3, 2),                                # int where numba's typeof says float64 is wanted
    (3, np.float32(1.5)),
    (4, 2.0),
    (4, True),                             # numba types a bool as boolean, not int64
    (5, 1),
    (5, np.int64(1)),
])
def test_arguments_off_the_signature_go_to_numba(position, bad):
    """Each argument is checked against the kernel's one signature as numba's ``typeof`` types it: a mismatch goes
    to numba's dispatcher (which converts, compiles or refuses, as before), never to the stored machine code, which
    would read the wrong memory."""
    calls = []
    stored = mc._Stored(lambda *a: calls.append("stored") or "stored", SPEC,
                        lambda: (lambda *a: calls.append("numba") or "numba"), "k")
    assert stored(*_good()) == "stored"
    args = _good()
    args[position] = bad
    assert stored(*args) == "numba"
    assert stored(*_good()[:-1]) == "numba"  # the wrong number of arguments
    assert calls == ["stored", "numba", "numba"]


def test_read_only_and_strided_views():
    """A read-only array (numba types it as another, immutable array) goes to numba; a strided 2-D view is fine
    where the signature says layout 'A', and numpy scalars of the right type are fine."""
    stored = mc._Stored(lambda *a: "stored", SPEC, lambda: (lambda *a: "numba"), "k")
    ro = np.zeros(3)
    ro.flags.writeable = False
    args = _good()
    args[0] = ro
    assert stored(*args) == "numba"
    args = _good()
    args[1] = np.zeros((4, 6))[::2, ::2]
    args[3], args[4], args[5] = np.float64(1.5), np.int64(2), np.bool_(True)
    assert stored(*args) == "stored"


def test_the_store_key_follows_the_kernels_sources(tmp_path, monkeypatch):
    """The store's key changes with any byte of a kernel's source (a stale store is never linked) and is the same
    for the same sources."""
    ll = mc._llvm()
    for rel in mc.KERNEL_SOURCES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(mc._PACKAGE / rel, tmp_path / rel)
    monkeypatch.setattr(mc, "_PACKAGE", tmp_path)
    key = mc._key(ll)
    assert mc._key(ll) == key
    for rel in mc.KERNEL_SOURCES:
        original = (tmp_path / rel).read_bytes()
        (tmp_path / rel).write_bytes(original + b"\n")
        assert mc._key(ll) != key, rel
        (tmp_path / rel).write_bytes(original)
    assert mc._key(ll) == key
    monkeypatch.setenv("NUMBA_OPT", "2")
    assert mc._key(ll) != key


def test_an_unresolved_symbol_refuses_the_entry():
    """A stored object that needs a symbol this process does not have is not linked (LookupError; the kernel then
    goes through numba, :func:`diffusion_pr._machine_code.kernel`)."""
    linker = mc._Linker(mc._llvm())
    entry = {"qualname": "k", "module": "m", "symbols": {"diffusion_pr_no_such_symbol_anywhere": ("process",)}}
    with pytest.raises(LookupError, match="diffusion_pr_no_such_symbol_anywhere"):
        linker.link(entry)


def test_elf_symbols_of_a_stored_kernel():
    """The object file's own symbol table lists what the staged kernel defines (its CPython wrapper and
    environment) and what it needs from numba's runtime and helpers."""
    from diffusion_pr.solvers.fv import _kernels

    dispatcher = _kernels.staged_run_rows_kernel()
    (cres,) = dispatcher.overloads.values()
    entry = mc._entry("diffusion_pr.solvers.fv._kernels", "staged_run_rows_kernel", dispatcher)
    if entry is None:
        pytest.skip("this process loaded the kernel numba's own way (no object code kept)")
    defined = mc.elf_symbols(entry["object"])
    needed = mc.elf_symbols(entry["object"], undefined=True)
    assert cres.fndesc.llvm_cpython_wrapper_name in defined and cres.fndesc.env_name in defined
    assert {"NRT_MemInfo_alloc_aligned", "numba_unpickle"} <= needed
    assert entry["symbols"]["NRT_MemInfo_alloc_aligned"] == ("nrt", "MemInfo_alloc_aligned")
    assert entry["symbols"]["numba_unpickle"] == ("unpickle",)
    assert mc.elf_symbols(b"not an object") is None


def test_a_damaged_store_is_rewritten(tmp_path):
    """A store file that does not unpickle (a disk error, a foreign file) is not used and is rewritten by the next
    kernel that loads through numba; the process's answers come from numba meanwhile."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), mc.ENV_MACHINE_CODE: "1"}
    code = ("import json; from diffusion_pr import _machine_code as mc; "
            "p = mc.store_path(); p.parent.mkdir(parents=True, exist_ok=True); "
            "open(p, 'wb').write(b'not a pickle') if not p.exists() else None; "
            "from diffusion_pr._closure_rows import model_rows; import numpy as np; "
            "rows = model_rows(np.array([1.0]), np.array([1.0]), np.array([0.5, 2.0]), 0); "
            "print(json.dumps([mc.status()['why'], mc.status()['numba'], rows.tolist(), str(p)]))")
    first = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                      env=env).stdout.strip().splitlines()[-1])
    assert first[0].startswith("damaged store") and first[1] == ["diffusion_pr._closure_kernels._rows_kernel"]
    assert first[2] == [[(0.5 / 1.5) ** 2, (2.0 / 3.0) ** 2]]
    second = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                       env=env).stdout.strip().splitlines()[-1])
    assert second[0].startswith("1 kernels stored") and second[1] == [] and second[2] == first[2]


def test_the_store_folder(tmp_path, monkeypatch):
    """NUMBA_CACHE_DIR first; else the package's __pycache__ where it can be written; else the user's cache folder
    (an installation the user cannot write to, as numba's own user-wide fallback)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert mc.store_folder() == tmp_path / "numba" / "diffusion_pr"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setattr(mc.os, "access", lambda path, mode: True)
    assert mc.store_folder() == mc._PACKAGE / "__pycache__"
    monkeypatch.setattr(mc.os, "access", lambda path, mode: False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert mc.store_folder() == tmp_path / "cache" / "diffusion_pr"
