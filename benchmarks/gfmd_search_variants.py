"""GFMD hard wall, ``ccg``: the search with and without the increments of ``u`` on hard cases.

Three variants of ``gfmd_ref.solver``'s switches: the default (``u`` by single-precision increments ``G dv`` between
exact ones, ``INCREMENT_U32``, with ``-tau G t`` for a step that kept the contact set, ``INCREMENT_REUSE_R``), the
increments with an FFT pair for every one of them, and an exact ``u = G p`` after every step (the previous solver).
Scenes: the Fig. 1 surface (``fig1_surface``) at n = 100, 255 (odd: the scipy FFT path), 256 and 512, seeds 1-2, mean
pressures from tiny contact areas (1e-5 E*-units, a few nodes in contact) to nearly full contact (0.05; 0.3 is full
contact, solved without iterating); the paper's Fig. 1 scene sampled coarsely (n = 32, 64, 128 on ``L = 1024``, seeds
1-3, the main job's test sizes); and a sinusoid and an egg-box at 128^2. tol 1e-9. Printed per scene: the iterations
of each variant, the default's increments (those that reused ``r``) and exact (double) pairs, whether each converged,
the contact fraction, and the largest pressure difference between the default's answer and the others' (in units of
p0).

    python benchmarks/gfmd_search_variants.py

Writes ``results/gfmd_search_variants.md``.  A few minutes.
"""
from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np

import gfmd_ref as g
from gfmd_ref import HardWall, solve_contact

from bench_gfmd import solver_switches

OUT = Path(__file__).resolve().parent / "results" / "gfmd_search_variants.md"
VARIANTS = {"default": {}, "no reuse": {"INCREMENT_REUSE_R": False}, "exact u": {"INCREMENT_U32": False}}
TOL = 1e-9


def solve(h, length, p0, flags):
    with solver_switches(**flags), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return solve_contact(h, length=length, E_star=8 / 3, mean_pressure=p0, interaction=HardWall(), tol=TOL,
                             method="ccg")


def scenes():
    for n, seed, p0 in itertools.product((100, 255, 256, 512), (1, 2), (1e-5, 1e-4, 0.004, 0.05, 0.3)):
        h, length = g.fig1_surface(n, seed=seed)
        yield f"Fig. 1, n = {n}, seed {seed}", h, length, p0
    from diffusion_pr.fig1 import FIG1_SCENE as S

    for n, seed in itertools.product((32, 64, 128), (1, 2, 3)):
        h = g.self_affine_surface(n, length=S["length"], hurst=S["hurst"], q_min=S["q_min"], q_max=S["q_max"],
                                  rms_slope=S["rms_slope"], seed=seed)
        yield f"Fig. 1 scene, L = 1024, n = {n}, seed {seed}", h, S["length"], S["mean_pressure"]
    x = np.arange(128) / 128
    for name, h in (("sinusoid, 128^2", np.cos(2 * np.pi * x)[:, None] * np.ones(128)[None, :]),
                    ("egg-box, 128^2", np.cos(2 * np.pi * x)[:, None] * np.cos(2 * np.pi * x)[None, :])):
        for p0 in (0.01, 0.5):
            yield name, np.ascontiguousarray(h), 128.0, p0


def main() -> None:
    lines = [f"# `ccg` search variants on hard cases (tol {TOL:g})", "",
             "Iterations: default (increments of `u`, `-tau G t` where a step kept the contact set) / increments each "
             "with its FFT pair / an exact `u` after every step (the previous solver). `dp`: the largest difference "
             "of the default's answer from the others', in p0.", "",
             "| scene | p0 | contact | iterations | default: increments (reusing `r`), exact pairs | converged "
             "| dp [p0] |",
             "|---|---|---|---|---|---|---|"]
    fewer = same = more = 0
    for name, h, length, p0 in scenes():
        res = {k: solve(h, length, p0, v) for k, v in VARIANTS.items()}
        d, prev = res["default"], res["exact u"]
        dp = max(float(np.max(np.abs(d.pressure - r.pressure))) for r in res.values()) / p0
        its = " / ".join(str(r.iterations) for r in res.values())
        fewer += d.iterations < prev.iterations
        same += d.iterations == prev.iterations
        more += d.iterations > prev.iterations
        row = (f"| {name} | {p0:g} | {d.contact_fraction:.4f} | {its} | {d.info.get('u_increments', 0)} "
               f"({d.info.get('u_increments_reusing_r', 0)}), "
               f"{d.info.get('fft_pairs', 0) - d.info.get('fft_pairs_single', 0)} | "
               f"{'/'.join('yes' if r.converged else 'NO' for r in res.values())} | {dp:.1e} |")
        print(row, flush=True)
        lines.append(row)
    lines += ["", f"Default against an exact `u`: fewer iterations in {fewer} scenes, the same in {same}, "
                  f"more in {more}."]
    OUT.write_text("\n".join(lines) + "\n")
    print(lines[-1])
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
