"""Contact solvers: constrained CG (hard wall), dual Newton-CG (exponential wall), FIRE (both),
picked by :func:`solve_contact`; they share one iteration monitor (:mod:`.monitor`) and the
compiled kernels of :mod:`._kernels`."""
from .api import EXP_CONTACT_THRESHOLD, METHODS, ContactResult, ConvergenceWarning, solve_contact

__all__ = ["solve_contact", "ContactResult", "ConvergenceWarning", "METHODS", "EXP_CONTACT_THRESHOLD"]
