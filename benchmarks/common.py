"""Shared pieces of the benchmarks: the scenes, exact answers, timing and Markdown tables.

Every benchmark script has ``run(quick: bool) -> str``, which prints its table and returns it as a Markdown
section; ``run_all.py`` collects the sections into ``benchmarks/RESULTS.md``.  Raw outputs and plots go to
``benchmarks/results/`` (not tracked).  Only the packages' public API is used.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
if str(HERE.parent) not in sys.path:  # the benchmarks measure the source tree they belong to
    sys.path.insert(0, str(HERE.parent))
#: the paper's Fig. 1 scene: contact modulus and mean pressure [units of E*]
E_STAR, P0 = 8.0 / 3.0, 0.004
#: the paper's cutoff pressure per wall range zeta (Muser's cutoff in the second-order theory)
PAPER_PC = {4.0: 0.0027, 1.0: 0.0027, 0.25: 0.0027, 0.01: 0.0082}
#: the shell closures timed on the Fig. 1 spectrum
CLOSURES = ("local_g1", "local_g1_balanced", "local_g1_shell_balanced")
CLOSURE_ZETAS = (4.0, 1.0, 0.25, 0.1, 0.01, 0.001)


def fig1_spectrum():
    """The Fig. 1 continuum spectrum: ``H = 0.3``, ``q = 2 pi/1024 ... 2 pi/32``, rms slope 0.031."""
    import diffusion_pr as dp

    return dp.SelfAffineSpectrum(0.3, 2 * np.pi / 1024, 2 * np.pi / 32, rms_slope=0.031)


def fig1_scene(zeta: float) -> tuple:
    """``(p0, V, f)`` of the second-order theory on the Fig. 1 scene at ``zeta``: Muser's cutoff at the paper's
    ``p_c`` with the Gaussian tail."""
    import diffusion_pr as dp

    V = float(dp.stress_variance(fig1_spectrum(), E_star=E_STAR, mean_pressure=P0, zeta=zeta))
    return P0, V, dp.PressureFactor(dp.MuserCutoff(PAPER_PC[zeta]), dp.GaussianTail())


def cell_masses(density: Callable, edges: np.ndarray, n: int = 8) -> np.ndarray:
    """``integral density`` over each cell of ``edges`` by ``n``-point Gauss-Legendre."""
    x, w = np.polynomial.legendre.leggauss(n)
    a, b = edges[:-1], edges[1:]
    pts = 0.5 * (b - a)[:, None] * x[None, :] + 0.5 * (a + b)[:, None]
    return np.sum(0.5 * (b - a)[:, None] * w[None, :] * density(pts), axis=1)


def answer_edges(result) -> np.ndarray:
    """The answer's cell edges, or edges between its points where it has none."""
    edges = getattr(result, "edges", None)
    if edges is not None:
        return np.asarray(edges, dtype=float)
    p = np.asarray(result.p, dtype=float)
    return np.concatenate(([0.5 * p[0]], 0.5 * (p[1:] + p[:-1]), [p[-1] + 0.5 * (p[-1] - p[-2])]))


def l1_to_density(result, density: Callable, zero_weight: float) -> float:
    """L1 error of an answer: its masses on its own cells (from ``result.cdf`` at the edges) against the exact
    ``density``'s, plus the error of the non-contact weight; the exact mass below the first edge counts as
    non-contact."""
    e = answer_edges(result)
    below = float(cell_masses(density, np.array([0.0, e[0]]), 24)[0]) if e[0] > 0 else 0.0
    return float(np.sum(np.abs(np.diff(result.cdf(e)) - cell_masses(density, e)))
                 + abs(result.zero_weight - zero_weight - below))


def l1_to_answer(result, reference) -> float:
    """L1 distance of an answer from a (much finer) reference answer on the answer's cells, plus the difference
    of their non-contact weights, the reference's mass below the answer's first edge counted as non-contact."""
    e = answer_edges(result)
    ref = np.asarray(reference.cdf(e), dtype=float)
    return float(np.sum(np.abs(np.diff(result.cdf(e)) - np.diff(ref))) + abs(result.zero_weight - ref[0]))


def interleaved(calls: dict, repeats: int, warm: bool = True) -> dict:
    """Median wall time [s] of each call in ``calls`` over ``repeats`` rounds, the calls interleaved within
    every round so that all see the machine in the same state; one discarded warm-up call each."""
    if warm:
        for call in calls.values():
            call()
    times: dict = {k: [] for k in calls}
    for _ in range(repeats):
        for k, call in calls.items():
            t0 = time.perf_counter()
            call()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def fmt(x: Optional[float], spec: str = ".3g") -> str:
    """A number for a table; ``-`` for None or NaN."""
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return format(x, spec)


def table(header: Sequence[str], rows: Iterable[Sequence]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def section(title: str, body: str, *notes: str) -> str:
    """A Markdown section (``## title``), printed, and returned for RESULTS.md."""
    text = f"## {title}\n\n{body}\n" + "".join(f"\n{n}\n" for n in notes if n)
    print(text, flush=True)
    return text


def cli(run: Callable, doc: str) -> None:
    """The command line of one script: ``--quick``; prints the section."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short settings (a run of the whole suite in minutes)")
    run(ap.parse_args().quick)
