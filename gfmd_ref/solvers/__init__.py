"""Contact solvers: constrained CG (hard wall), dual Newton-CG (exponential wall), FIRE (both).

:func:`solve_contact` (:mod:`~gfmd_ref.solvers.api`) picks one; the three algorithms
(:mod:`~gfmd_ref.solvers.ccg`, :mod:`~gfmd_ref.solvers.newton`,
:mod:`~gfmd_ref.solvers.fire`) share one iteration monitor
(:mod:`~gfmd_ref.solvers.monitor`) and the compiled kernels of
:mod:`~gfmd_ref.solvers._kernels`.
"""
from .api import EXP_CONTACT_THRESHOLD, METHODS, ContactResult, ConvergenceWarning, solve_contact

__all__ = ["solve_contact", "ContactResult", "ConvergenceWarning", "METHODS", "EXP_CONTACT_THRESHOLD"]
