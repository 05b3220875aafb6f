"""Bundled GFMD reference data for the paper's Fig. 1 system, and its generator.

The Fig. 1 system of Müser, PRL 100, 055504 (2008) (numbers in :mod:`diffusion_pr.paper`): a ``1024 x 1024`` grid of
period ``L = 1024`` (the grid spacing is the length unit), exponential repulsion at several ``zeta`` and the hard wall.
Each case is a compressed ``.npz`` in ``diffusion_pr/data/`` holding the pressure histogram
(:class:`~diffusion_pr.compare.SimulatedHistogram`), the surface's :class:`~diffusion_pr.spectra.DiscreteSpectrum` and
the provenance, including the command that regenerates it (:func:`generate_reference`, ``diffusion-pr make-reference``).
Loading needs only numpy; generating needs :mod:`gfmd_ref`."""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np

from ..compare import SimulatedHistogram
from ..paper import FIG1_SCENE, LARGE_ZETA, N_WAVES, cutoff_pressure
from ..spectra import DiscreteSpectrum

DATA_DIR = Path(__file__).resolve().parent.parent / "data"

#: zeta values (units of the grid spacing) of the bundled exponential-wall cases.
FIG1_ZETAS: tuple[float, ...] = (0.001, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)

#: The paper's cutoff pressure for each bundled zeta it covers (0.1 lies between the
#: paper's groups and is left out), derived from :mod:`diffusion_pr.paper`.
PAPER_CUTOFF_PRESSURES: dict[float, float] = {
    z: cutoff_pressure(z) for z in FIG1_ZETAS if z in (0.001, 0.01) or z >= LARGE_ZETA}


def case_name(zeta: Optional[float], seed: int, n: int = 1024, surface: str = "fig1") -> str:
    """File stem of a case: ``fig1_n1024_hard_s1`` or ``fig1_n1024_zeta0.25_s1``."""
    wall = "hard" if zeta is None or zeta == 0 else f"zeta{zeta:g}"
    return f"{surface}_n{n}_{wall}_s{seed}"


def fig1_heights(n: int, seed: Any, surface: str = "fig1") -> np.ndarray:
    """The Fig. 1 surface on an ``n x n`` grid of the paper's period ``L = 1024`` (lengths in grid spacings of
    the 1024^2 system): Gaussian coloured noise (``"fig1"``) or its :func:`skewed_surface` (``"fig1-skewed"``)."""
    import gfmd_ref

    s = FIG1_SCENE
    heights = gfmd_ref.self_affine_surface(n, length=s["length"], hurst=s["hurst"], q_min=s["q_min"],
                                           q_max=s["q_max"], rms_slope=s["rms_slope"], seed=seed)
    if surface == "fig1-skewed":
        heights = skewed_surface(heights, length=s["length"], rms_slope=s["rms_slope"])
    return heights


def solve_fig1_wall(heights: np.ndarray, zeta: Optional[float], *, tol: float, progress: bool) -> tuple[Any, float]:
    """GFMD on the Fig. 1 scene at the wall range ``zeta`` (None: the hard wall): ``(ContactResult, seconds)``."""
    import gfmd_ref

    s, t0 = FIG1_SCENE, time.perf_counter()
    wall = gfmd_ref.HardWall() if zeta is None else gfmd_ref.ExponentialRepulsion(zeta)
    res = gfmd_ref.solve_contact(heights, length=s["length"], E_star=s["E_star"], mean_pressure=s["mean_pressure"],
                                 interaction=wall, tol=tol, progress=progress)
    return res, time.perf_counter() - t0


@dataclass(frozen=True)
class ReferenceCase:
    """One bundled GFMD result: its ``histogram``, the surface's own ``spectrum`` (for the theory curve), the wall
    range ``zeta`` (the spectrum's length unit, the paper's; ``None`` for the hard wall) and the ``provenance``."""

    name: str
    zeta: Optional[float]
    histogram: SimulatedHistogram
    spectrum: Any
    provenance: dict

    @property
    def E_star(self) -> float:
        """Contact modulus of the run (units of pressure)."""
        return float(self.provenance["E_star"])

    @property
    def mean_pressure(self) -> float:
        """Mean pressure of the run (units of pressure)."""
        return float(self.provenance["mean_pressure"])


def paper_theory(case: Any, *, cutoff: str = "muser", p_c: Optional[float] = None, backend: str = "auto",
                 rtol: float = 1e-5) -> Any:
    """The paper's theory curve for one case (a :class:`ReferenceCase` or any object with ``zeta``, ``spectrum``,
    ``E_star``, ``mean_pressure``): the one definition the main job and the claims tests use.

    Hard wall (``case.zeta`` is None): Persson's mirror Gaussian.  Exponential wall: the second-order cumulant
    theory with ``G1`` (Eq. 10) from the case's own spectrum, ``cutoff`` (``"muser"``: the paper's literal one),
    and ``p_c`` (pressure) defaulting to the paper's value (:func:`diffusion_pr.paper.cutoff_pressure`);
    ``backend`` and ``rtol`` go to :func:`diffusion_pr.pressure_distribution`."""
    from ..api import pressure_distribution

    kw = {"zeta": 0.0} if case.zeta is None else {
        "zeta": case.zeta, "cutoff": cutoff, "p_c": cutoff_pressure(case.zeta) if p_c is None else p_c,
        "backend": backend, "rtol": rtol}
    return pressure_distribution(case.spectrum, E_star=case.E_star, mean_pressure=case.mean_pressure,
                                 closure="second_order", **kw)


def available_references(data_dir: Path | str | None = None) -> list[str]:
    """Names of the bundled cases (file stems), sorted."""
    folder = Path(data_dir) if data_dir is not None else DATA_DIR
    return sorted(p.stem for p in folder.glob("*.npz"))


def load_reference(name: str, data_dir: Path | str | None = None) -> ReferenceCase:
    """Load a bundled case by name (see :func:`available_references`).

    Raises
    ------
    ValueError
        If no such case is bundled (the message lists the available ones).
    """
    folder = Path(data_dir) if data_dir is not None else DATA_DIR
    path = folder / f"{name}.npz"
    if not path.exists():
        raise ValueError(f"no reference case {name!r}; available: {available_references(folder)}")
    with np.load(path, allow_pickle=False) as data:
        prov = json.loads(str(data["provenance"]))
        hist = SimulatedHistogram(edges=data["edges"], density=data["density"], zero_weight=float(data["zero_weight"]),
                                  moments=json.loads(str(data["moments"])), quantile_levels=data["quantile_levels"],
                                  quantiles=data["quantiles"], metadata=prov)
        spectrum = DiscreteSpectrum(data["spectrum_q"], data["spectrum_power"], data["spectrum_multiplicity"],
                                    float(prov["length"]))
    zeta = prov.get("zeta")
    return ReferenceCase(name, None if zeta is None else float(zeta), hist, spectrum, prov)


def save_case(path: Path, pressure: np.ndarray, heights: np.ndarray, provenance: dict,
              bin_width: float) -> SimulatedHistogram:
    """Histogram a pressure field and write one ``.npz`` case (compressed)."""
    edges = np.arange(max(10, int(math.ceil(float(pressure.max()) / bin_width))) + 1) * bin_width
    hist = SimulatedHistogram.from_pressures(pressure, bins=edges, metadata=provenance)
    spectrum = DiscreteSpectrum.from_heights(heights, float(provenance["length"]))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, edges=hist.edges, density=hist.density, zero_weight=hist.zero_weight,
                        moments=json.dumps(hist.moments), quantile_levels=hist.quantile_levels,
                        quantiles=hist.quantiles, spectrum_q=spectrum.q, spectrum_power=spectrum.power,
                        spectrum_multiplicity=spectrum.multiplicity, provenance=json.dumps(provenance, sort_keys=True))
    return hist


def generate_reference(*, zetas: Iterable[Optional[float]] = (None, *FIG1_ZETAS), seeds: Sequence[int] = (1,),
                       n: int = 1024, tol: float = 1e-6, out_dir: Path | str = "reference_out",
                       surface: str = "fig1", progress: bool = True, log: Any = print) -> list[Path]:
    """Run GFMD on the Fig. 1 system and write the bundled cases.

    ``zetas``: wall ranges in grid spacings of the paper's 1024^2 system (the cell stays ``L = 1024`` at every
    ``n``), ``None`` the hard wall; ``seeds``: surface seeds; ``n`` >= 64 grid points per side (the shortest
    wavelength needs 2); ``tol``: GFMD tolerance relative to ``p0``; ``out_dir``: checked for writability before
    any work (the bundled cases live in :data:`DATA_DIR`: pass it explicitly to replace them); ``surface``:
    ``"fig1"`` (Gaussian coloured noise) or ``"fig1-skewed"`` (:func:`skewed_surface` of it)."""
    import gfmd_ref
    from gfmd_ref.ensemble import code_version

    from .._validation import check_int, check_positive, check_seed, check_writable

    if surface not in ("fig1", "fig1-skewed"):
        raise ValueError(f"surface must be 'fig1' or 'fig1-skewed'; got surface={surface!r}")
    n = check_int("n", n, minimum=2)
    if n < 2 * N_WAVES:
        raise ValueError(f"n must be >= {2 * N_WAVES}: the roughness's shortest wavelength L/{N_WAVES} needs 2 grid "
                         f"points (Nyquist); got n={n}")
    check_positive("tol", tol)
    zetas, seeds = list(zetas), [check_seed("seeds", seed) for seed in seeds]
    for name, items in (("zetas", zetas), ("seeds", seeds)):
        if not items:
            raise ValueError(f"{name} must hold at least one entry; got {name}={items!r}")
    for zeta in zetas:
        if zeta is not None:
            gfmd_ref.ExponentialRepulsion(check_positive("zeta", zeta))
    if out_dir is None:
        raise ValueError("out_dir must be a folder (the package's data folder only when given explicitly)")
    folder = Path(check_writable("out_dir", out_dir))
    made_by = code_version()  # package version and git revision (+dirty), as the ensemble records

    written = []
    for seed in seeds:
        heights = fig1_heights(n, seed, surface)
        for zeta in zetas:
            res, wall = solve_fig1_wall(heights, zeta, tol=tol, progress=progress)
            name = case_name(zeta, seed, n, surface)
            cmd = (f"diffusion-pr make-reference --n {n} --seeds {seed} --tol {tol:g} --surface {surface} "
                   f"--length-unit paper --zetas {'hard' if zeta is None else f'{zeta:g}'}")
            prov = {
                **FIG1_SCENE, "n": n, "zeta": zeta, "interaction": "hard" if zeta is None else "exponential",
                "seed": int(seed), "surface": surface, "tol": tol, "method": res.method,
                "converged": bool(res.converged), "residual": float(res.residual),
                "iterations": int(res.iterations), "wall_time_s": round(wall, 3),
                "contact_fraction": float(res.contact_fraction),
                "code_version": f"{made_by['version']} (git {made_by['git']})",
                "command": cmd,
            }
            save_case(folder / f"{name}.npz", np.asarray(res.pressure), np.asarray(heights), prov,
                      bin_width=FIG1_SCENE["mean_pressure"] / 20.0)
            log(f"{name}: converged={res.converged} residual={res.residual:.2e} it={res.iterations} "
                f"a={res.contact_fraction:.5f} {wall:.1f} s")
            written.append(folder / f"{name}.npz")
    return written


def skewed_surface(heights: np.ndarray, *, length: float, rms_slope: float, skew: float = 1.0) -> np.ndarray:
    """A non-Gaussian surface made from a coloured-noise ``(n, n)`` height map of period ``length``.

    ``h' = exp(skew * h / h_rms)`` (``skew`` > 0), centred and rescaled to ``rms_slope`` (computed spectrally):
    positive skewness (sharper peaks, flatter valleys), Fourier modes correlated."""
    h = np.asarray(heights, dtype=float)
    out = np.exp(skew * (h - h.mean()) / h.std())
    out -= out.mean()
    n = h.shape[0]
    k = 2.0 * math.pi / length * np.fft.fftfreq(n, d=1.0 / n)
    ht = np.fft.fft2(out) / (n * n)
    slope2 = float(np.sum((k[:, None] ** 2 + k[None, :] ** 2) * np.abs(ht) ** 2))
    return out * (rms_slope / math.sqrt(slope2))
