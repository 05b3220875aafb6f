"""Cold start: the first solve in a fresh process, the kernels' stored machine code against numba's cache loads.

Each measurement is one fresh Python process (warm on-disk caches, as on every run
after the first one after installing) that imports ``diffusion_pr`` (lazy), builds
the Fig. 1 spectrum (this imports numpy and scipy; reported apart), then times its
first solve and a second, warm one. The ways of loading the compiled kernels alternate process by process in every
round:

* ``stored``: the default since the forty-ninth session, the kernels' machine code linked from the package's store
  by llvmlite, numba not imported (:mod:`diffusion_pr._machine_code`);
* ``package``: numba's cache (``DIFFUSION_PR_MACHINE_CODE=0``, as every mode below), loaded without numba's
  registry refresh, with their shared bitcode
  parsed only when linked, numba's runtime from the package's cache and numba's environments rebuilt without
  their modules' imports (:mod:`diffusion_pr._numba_load`);
* ``eager``: the package's load with numba's own unserialization (``DIFFUSION_PR_NUMBA_LAZY_LINK=0``: each
  kernel's shared bitcode parsed on load, as numba does, not when first linked);
* ``nrt``: the package's load with numba's runtime functions compiled in the process, as numba does
  (``DIFFUSION_PR_NUMBA_NRT_CACHE=0``), not loaded from the package's cache of their machine code;
* ``env``: the package's load with the environments of numba's own functions rebuilt numba's way, importing
  their modules (``DIFFUSION_PR_NUMBA_LAZY_ENV=0``);
* ``numba``: ``DIFFUSION_PR_NUMBA_REFRESH=1``, numba's own load (refresh included).

Cases: the paper's problem (``propagate``; no numba at all) and the three shell
closures on the Fig. 1 scene of ``ab_closures.py`` (``H = 0.3``, ``E* = 8/3``, ``p0 = 0.004``) for each
``zeta``. Target (issue 10): the first solve under 0.3 s. Medians over ``--rounds``
processes per case and mode; writes ``results/cold_start.{json,md}``.

Usage: ``python benchmarks/cold_start.py [--rounds 5] [--quick]``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

OUT = Path(__file__).resolve().parent / "results"

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import diffusion_pr as dp
t1 = time.perf_counter()
case, zeta = sys.argv[1], float(sys.argv[2])
if case == "paper":
    import numpy as np
    t2 = time.perf_counter()
    call = lambda: dp.propagate(0.004, 0.03 ** 2, diffusivity=dp.PressureFactor(dp.MuserCutoff(0.0027),
                                dp.GaussianTail()), backend="native", rtol=1e-6)
else:
    import numpy as np
    S = dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)
    t2 = time.perf_counter()
    call = lambda: dp.pressure_distribution(S, E_star=8 / 3, mean_pressure=0.004, zeta=zeta, closure=case,
                                            rtol=1e-6)
r = call()
t3 = time.perf_counter()
r2 = call()
t4 = time.perf_counter()
print(json.dumps(dict(import_s=t1 - t0, setup_s=t2 - t1, first_s=t3 - t2, second_s=t4 - t3,
                      success=bool(r.success), numba="numba" in sys.modules,
                      refreshed="numba.np.linalg" in sys.modules)))
"""

MODES = ("stored", "package", "eager", "nrt", "env", "numba")
CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")
ZETAS = (0.001, 0.01, 0.1, 0.25, 1.0, 4.0)


def child(case: str, zeta: float, mode: str, keep_env: bool = False) -> dict:
    env = {**os.environ, "DIFFUSION_PR_MACHINE_CODE": "1" if mode == "stored" else "0",
           "DIFFUSION_PR_NUMBA_REFRESH": "1" if mode == "numba" else "0",
           "DIFFUSION_PR_NUMBA_LAZY_LINK": "0" if mode == "eager" else "1",
           "DIFFUSION_PR_NUMBA_NRT_CACHE": "0" if mode == "nrt" else "1",
           "DIFFUSION_PR_NUMBA_LAZY_ENV": "0" if mode == "env" else "1"}
    if not keep_env:  # as a default Python installation: byte code cached (this sandbox sets the variable)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, "-c", CHILD, case, repr(zeta)], capture_output=True, text=True,
                         check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


NUMBA_ALONE = r"""
import json, time
import numpy
t0 = time.perf_counter()
import numba
print(json.dumps(dict(numba_import_s=time.perf_counter() - t0)))
"""


def numba_import(keep_env: bool = False) -> float:
    """Seconds of ``import numba`` alone in a fresh process (numpy imported before): a floor under every first
    closure solve, whose kernels are numba's."""
    env = dict(os.environ)
    if not keep_env:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, "-c", NUMBA_ALONE], capture_output=True, text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])["numba_import_s"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=None,
                    help="fresh processes per case and mode (default: 5, or 3 with --quick)")
    ap.add_argument("--quick", action="store_true",
                    help="zeta 0.01 and 0.25 only, 3 rounds unless --rounds says (default: off)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES,
                    help="the loads to compare, the first one the headline (default: all)")
    ap.add_argument("--keep-env", action="store_true",
                    help="keep PYTHONDONTWRITEBYTECODE if set (default: removed, so that the package's "
                         "modules load from cached byte code as in a default installation)")
    args = ap.parse_args()
    keep = args.keep_env
    modes = tuple(args.modes)
    rounds = args.rounds if args.rounds is not None else (3 if args.quick else 5)
    zetas = (0.01, 0.25) if args.quick else ZETAS
    cases = [("paper", 0.0)] + [(c, z) for c in CLOSURES for z in zetas]
    for case, zeta in cases[:2]:  # caches warm (a first run after installing compiles here)
        child(case, zeta, "stored", keep)  # (a store missing a kernel gets it here)
    t_start = time.time()
    runs = {(c, z, m): [] for c, z in cases for m in modes}
    numba_alone = []
    for rnd in range(rounds):
        numba_alone.append(numba_import(keep))
        for c, z in cases:
            for m in (modes if rnd % 2 == 0 else modes[::-1]):
                runs[(c, z, m)].append(child(c, z, m, keep))
        print(f"round {rnd + 1}/{rounds} done ({time.time() - t_start:.0f} s)", flush=True)
    rows = []
    for c, z in cases:
        row = dict(case=c, zeta=z)
        for m in modes:
            rs = runs[(c, z, m)]
            assert all(r["success"] for r in rs), (c, z, m)
            row[m] = {k: statistics.median(r[k] for r in rs) for k in ("setup_s", "first_s", "second_s")}
            row[m]["refreshed"] = sorted({r["refreshed"] for r in rs})
            row[m]["numba"] = sorted({r["numba"] for r in rs})
        rows.append(row)
    load = os.getloadavg()
    lines = [f"# Cold start: first solve in a fresh process (medians of {rounds} processes per cell, "
             f"load {load[0]:.2f})", "",
             "`stored`: the kernels' machine code from the package's store, numba not imported (the default); "
             "`package`: numba's cached kernels loaded without numba's registry refresh and with their shared "
             "bitcode parsed only when linked and numba's runtime loaded from the package's cache; `eager`: "
             "the same with numba's own unserialization (`DIFFUSION_PR_NUMBA_LAZY_LINK=0`); `nrt`: the same with "
             "numba's runtime compiled in the process (`DIFFUSION_PR_NUMBA_NRT_CACHE=0`); `env`: the same with the "
             "environments of numba's functions rebuilt numba's way (`DIFFUSION_PR_NUMBA_LAZY_ENV=0`); `numba`: "
             "`DIFFUSION_PR_NUMBA_REFRESH=1`. `setup`: importing numpy and building the spectrum (scipy.integrate "
             "too, before the thirty-seventh session). "
             "Target: first solve under 0.3 s. "
             + ("PYTHONDONTWRITEBYTECODE as set by the caller." if keep else
                "Byte code cached (PYTHONDONTWRITEBYTECODE removed), as in a default installation.")
             + f" `import numba` alone (numpy imported before), one fresh process per round: median "
               f"{statistics.median(numba_alone):.3f} s (range {min(numba_alone):.3f}-{max(numba_alone):.3f}).", "",
             f"| case | zeta | setup [s] | first solve, {modes[0]} [s] | setup + first, {modes[0]} [s] | "
             + " | ".join(f"{m} [s]" for m in modes[1:])
             + " | " + " | ".join(f"{modes[0]}/{m}" for m in modes[1:]) + " | numba imported | second solve [ms] |",
             "|---|---|---|---|---|" + "---|" * (2 * len(modes))]
    for row in rows:
        head = row[modes[0]]
        p, setup = head["first_s"], head["setup_s"]
        lines.append(f"| {row['case']} | {row['zeta']:g} | {setup:.3f} | {p:.3f} | {setup + p:.3f} | "
                     + " | ".join(f"{row[m]['first_s']:.3f}" for m in modes[1:]) + " | "
                     + " | ".join(f"{p / row[m]['first_s']:.2f}" for m in modes[1:])
                     + f" | {'/'.join(str(v) for v in head['numba'])} | {1e3 * head['second_s']:.1f} |")
    text = "\n".join(lines)
    print(text)
    OUT.mkdir(exist_ok=True)
    (OUT / "cold_start.md").write_text(text + "\n")
    (OUT / "cold_start.json").write_text(json.dumps(dict(rounds=rounds, load=load, rows=rows,
                                                          numba_import_s=numba_alone), indent=1))


if __name__ == "__main__":
    main()
