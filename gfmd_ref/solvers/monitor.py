"""The iteration monitor shared by the three contact solvers.

Every solver loop hands its residual to :meth:`Monitor.check` and stops when that returns
True. The monitor keeps the residual history, drives the optional tqdm bar, and decides
the stop: the tolerance, ``max_iter``, a non-finite residual, or a stall (the best
residual has not halved within ``window`` steps).
"""
from __future__ import annotations

import math

import numpy as np


class Monitor:
    """History, progress bar and stop rule of one solver run named ``name``: converged when a
    residual is below ``tol``; stopped at ``max_iter`` iterations or when the best residual
    has not halved within ``window`` steps (0: never; ``step`` names what the window counts
    in the message). ``progress`` shows a tqdm bar of the decades of residual reduction
    from the first residual down to ``tol`` (what the run will really do, not ``max_iter``).
    """

    def __init__(self, name: str, tol: float, max_iter: int, window: int, progress: bool = False,
                 step: str = "iteration"):
        self.name, self.tol, self.max_iter, self.window, self.step = name, tol, max_iter, int(window), step
        self.progress = bool(progress)
        self.history: list = []
        self.best, self.it_best = math.inf, 0
        self.converged, self.stop, self.residual = False, "max_iter", math.inf
        self._bar = self._res0 = None

    def done(self, res: float, it: int) -> bool:
        """Whether ``res`` at iteration ``it`` ends the run by tolerance or ``max_iter``
        (a solver may refine its residual before :meth:`check` records it)."""
        return res < self.tol or it >= self.max_iter

    def check(self, res: float, it: int, steps: int | None = None) -> bool:
        """Record the residual ``res`` reached after ``it`` iterations (``steps`` of the
        stall window, default ``it``); returns True when the run must stop
        (:attr:`converged`, :attr:`stop` say why)."""
        self.residual = res
        self.history.append(res)
        self._show(res, it)
        steps = it if steps is None else steps
        if res < self.tol:
            self.converged, self.stop = True, "converged"
        elif it >= self.max_iter:
            self.stop = "max_iter"
        elif not math.isfinite(res):
            self.stop = f"diverged: non-finite residual {res} at iteration {it}"
        elif res < 0.5 * self.best or not math.isfinite(self.best):
            self.best, self.it_best = res, steps
            return False
        elif self.window > 0 and steps - self.it_best >= self.window:
            self.stop = (f"stalled: best residual {self.best:.3e} (at {self.step} {self.it_best}) did not halve "
                         f"within {self.window} {self.step}s; last residual {res:.3e}")
        else:
            return False
        self.close()
        return True

    def fail(self, reason: str) -> None:
        """End the run for ``reason`` (not converged)."""
        self.converged, self.stop = False, reason
        self.close()

    def _show(self, res: float, it: int) -> None:
        if not self.progress or not math.isfinite(res) or res <= 0:
            return
        if self._bar is None:
            from tqdm.auto import tqdm

            self._res0 = max(res, self.tol)
            total = max(math.log10(self._res0 / self.tol), 1e-3)
            self._bar = tqdm(total=round(total, 2), desc=f"gfmd_ref {self.name}", unit="decade", leave=False,
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} "
                                        "decades [{elapsed}<{remaining}{postfix}]")
        done = min(self._bar.total, round(max(0.0, math.log10(self._res0 / max(res, 1e-300))), 2))
        if done > self._bar.n:
            self._bar.update(done - self._bar.n)
        self._bar.set_postfix(it=it, residual=f"{res:.2e}", refresh=False)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def outcome(self, iterations: int, **fields) -> dict:
        """The solver's answer with the run's record: ``converged``, ``iterations``,
        ``residual``, ``history``, ``stop`` beside the solver's ``fields``."""
        return dict(fields, converged=self.converged, iterations=iterations, residual=self.residual,
                    history=np.asarray(self.history), stop=self.stop)
