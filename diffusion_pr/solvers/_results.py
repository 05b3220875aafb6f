"""One place where a finite-volume backend turns its cell averages into a result.

The py-pde and FiPy backends share the bookkeeping a result must carry
(scipy-style contract): mass and mean conservation checked against ``rtol``,
negative densities reported (never silently clipped), the error estimate
against ``rtol``, and a status message that says how far the solver got.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from ..problem import FokkerPlanckProblem
from ..result import PressureDistribution


def finite_volume_result(problem: FokkerPlanckProblem, *, backend: str, edges: np.ndarray, density: np.ndarray,
                         zero_weight: float, rtol: float, estimate: float, refine: bool, wall_time: float,
                         work: str, failure: Optional[str], budget: str,
                         diagnostics: dict[str, Any]) -> PressureDistribution:
    """Check conservation and the estimate, build the message, return the result.

    Parameters
    ----------
    problem : FokkerPlanckProblem
    backend : str
        Backend name stored in the result.
    edges, density : ndarray
        Cell edges (units of pressure) and cell-average densities (1 / pressure).
    zero_weight : float
        Probability absorbed at ``p = 0``.
    rtol : float
        Requested L1 tolerance.
    estimate : float
        The backend's L1 error estimate.
    refine : bool
        Whether the estimate comes from a refinement (else: a single solve).
    wall_time : float
        Seconds.
    work : str
        What the final solve used, e.g. ``"1024 cells, 512 CN steps"``.
    failure : str or None
        The underlying solver's error, if it raised.
    budget : str
        The caps that stopped refinement, quoted when the estimate misses rtol.
    diagnostics : dict
        Backend-specific details; conservation numbers are added here.
    """
    h = np.diff(edges)
    p = 0.5 * (edges[:-1] + edges[1:])
    mass = float(np.sum(h * density) + zero_weight)
    mean = float(np.sum(h * p * density))
    negative = density < 0.0
    negative_mass = float(-np.sum(h[negative] * density[negative]))
    min_density = float(density.min()) if density.size else 0.0
    problems: list[str] = []
    if failure is not None:
        problems.append(f"{backend} failed on {work}: {failure}")
    if refine and not (estimate <= rtol):
        problems.append(f"error estimate {estimate:.2e} misses rtol={rtol:.1e} at {work} ({budget})")
    if abs(mass - 1.0) > rtol:
        problems.append(f"mass {mass:.12g} not conserved to rtol")
    if problem.drift is None and abs(mean - problem.mean_pressure) > rtol * problem.mean_pressure:
        problems.append(f"mean {mean:.8g} differs from p0={problem.mean_pressure:.8g} by more than rtol")
    negative_note = ""
    if negative_mass > 0.0:
        negative_note = (f"negative densities (min {min_density:.2e}, negative mass {negative_mass:.2e}) "
                         "kept, not clipped")
        if negative_mass > rtol:
            problems.append(negative_note)
    success = not problems
    if success:
        message = (f"converged: L1 error estimate {estimate:.2e} <= rtol {rtol:.1e} on {work}" if refine
                   else f"solved on {work} without refinement (no error estimate)")
        if negative_note:
            message += "; " + negative_note
    else:
        message = "; ".join(problems + ([negative_note] if negative_note and negative_note not in problems else []))
    diagnostics = dict(diagnostics)
    diagnostics.update(min_density=min_density, negative_mass=negative_mass, mass_error=mass - 1.0,
                       mean_error=mean - problem.mean_pressure)
    return PressureDistribution(p=p, density=density, weights=h, zero_weight=float(zero_weight),
                                mean_pressure=problem.mean_pressure, variance=problem.variance, backend=backend,
                                success=bool(success), message=message, error_estimate=float(estimate),
                                wall_time=float(wall_time), diagnostics=diagnostics, edges=edges)
