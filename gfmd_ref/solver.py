"""Contact solvers: GFMD (FIRE), constrained CG (hard wall), dual Newton-CG (exponential wall).

Geometry and conventions (docs/gfmd.md): rigid rough surface ``h`` (zero mean
not required), elastic half-space with contact modulus ``E*`` pressed on it with mean
pressure ``p0``. Solid surface ``z = z0 + u`` (``<u> = 0``), gap ``g = z - h``.
Each Fourier mode ``q != 0`` of ``u`` is a spring of stiffness ``q E*/2`` (per unit
area): the elastic pressure is ``p_el = p0 + IFFT[(q E*/2) FFT(z)]`` and, inversely,
``u = IFFT[(2/(q E*)) FFT(p)]``.

Residual definitions (all dimensionless, "relative to p0"; ``h_s`` = standard
deviation of the heights, or ``length`` for a flat surface):

* hard wall, ``method="ccg"`` (pressure variables, the displacement is computed from
  the pressure so the force balance of every mode holds by construction):
  ``max(|<p> - p0|/p0, max|p g|/(p0 h_s), max(-g)_+/h_s)``: load error,
  complementarity, penetration.
* hard wall, ``method="fire"`` (displacement variables, ``z >= h`` by projection):
  ``max(|<p> - p0|/p0, max over free nodes |p_el|/p0, max over contact nodes (-p_el)_+/p0)``:
  the force residual of every node (a free node must carry no pressure, a contact
  node no tension).
* exponential wall, both methods: ``max_i |sigma(g_i) - p_el,i| / p0``: the force
  residual of every node, where ``sigma = p0 exp(-g/zeta)`` (``v0 = zeta p0``).
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import _kernels as kr
from ._fft import check_threads, fft_pair
from ._validation import check_heights, check_int, check_positive
from .interactions import ExponentialRepulsion, HardWall

__all__ = ["solve_contact", "ContactResult", "ConvergenceWarning", "METHODS"]

#: methods available per interaction ("auto" picks the first, the fastest).
METHODS = {
    "HardWall": ("ccg", "pk", "fire"),
    "ExponentialRepulsion": ("newton", "fire"),
}

#: exponential wall: refuse problems whose round-off floor of the residual exceeds this.
EXP_FLOOR_LIMIT = 1e-3

#: exponential wall: contact means ``pressure > EXP_CONTACT_THRESHOLD * p0``.
EXP_CONTACT_THRESHOLD = 0.01


class ConvergenceWarning(UserWarning):
    """A solver stopped before reaching the requested tolerance."""


@dataclass(frozen=True, eq=False)
class ContactResult:
    """Solution of one contact problem.

    ``pressure`` has mean ``mean_pressure`` to round-off (load control), ``gap =
    displacement - heights``. ``contact_fraction``: hard wall, fraction of nodes with
    ``pressure > 0``; exponential wall, fraction with ``pressure > contact_threshold``
    (``EXP_CONTACT_THRESHOLD * p0 = 0.01 p0``). ``iterations`` counts the costly
    operator applications (one FFT pair each: CG/FIRE steps, Newton line-search
    evaluations). ``residual`` is relative to ``mean_pressure`` (see module doc).
    """

    pressure: np.ndarray
    gap: np.ndarray
    displacement: np.ndarray
    contact_fraction: float
    converged: bool
    iterations: int
    residual: float
    wall_time: float
    method: str
    message: str
    residual_history: np.ndarray
    interaction: object
    mean_pressure: float
    E_star: float
    length: float
    tol: float
    contact_threshold: float = 0.0
    info: dict = field(default_factory=dict)


#: work arrays of the FFT pair the hard-wall solver uses (pressure, displacement, direction, scratch)
N_WORK_ARRAYS = 4
#: single-precision work arrays of the ``ccg`` solver (the preconditioned gap, the direction, r = G t, and the
#: step's pressure change, :data:`INCREMENT_U32`; made once per pair by ``gfmd_ref.warm_up``)
N_SINGLE_ARRAYS = 4


class _Elastic:
    """Half-space Green's function on the rfft2 grid."""

    def __init__(self, n: int, length: float, E_star: float, threads: int | None = None):
        self.n = n
        self.shape = (n, n)
        self.length = length
        self.E_star = E_star
        kx = 2.0 * np.pi * np.fft.fftfreq(n, d=length / n)
        ky = 2.0 * np.pi * np.fft.rfftfreq(n, d=length / n)
        q = np.sqrt(kx[:, None] ** 2 + ky[None, :] ** 2)
        self.q = q
        self.K = 0.5 * E_star * q  # stiffness per unit area
        with np.errstate(divide="ignore"):
            G = np.where(q > 0, 2.0 / (E_star * np.where(q > 0, q, 1.0)), 0.0)
        self.G = G
        #: ``G / n^2``: the multiplier of :meth:`apply_into` (normalisation folded in)
        self.Gn = G / (n * n)
        self.q1 = 2.0 * np.pi / length
        # weights of the half spectrum in full-spectrum sums
        w = np.full(q.shape, 2.0)
        w[:, 0] = 1.0
        if n % 2 == 0:
            w[:, -1] = 1.0
        self.w = w
        # real-space diagonal of G: mean over the full spectrum of 2/(q E*)
        self.g_diag = float(np.sum(w * G)) / (n * n)
        # planned FFTW where available (about 4x faster at 1024^2), else scipy.fft
        self.fft, self.fft_planning_time = fft_pair(self.shape, threads)
        self.rfft = self.fft.rfft
        self.irfft = self.fft.irfft
        self.apply = self.fft.apply
        self.apply_into = self.fft.apply_into


class _Progress:
    """tqdm bar counting decades of residual reduction, from the first residual down to
    ``tol``: its total is what the solver will really do (not ``max_iter``), so its ETA
    is a real estimate; the postfix shows iterations and the residual."""

    def __init__(self, enabled: bool, desc: str, tol: float):
        self.enabled = bool(enabled)
        self.desc = desc
        self.tol = tol
        self.bar = None
        self.res0 = None

    def update(self, res: float, it: int) -> None:
        if not self.enabled or not math.isfinite(res) or res <= 0:
            return
        if self.bar is None:
            from tqdm.auto import tqdm

            self.res0 = max(res, self.tol)
            total = max(math.log10(self.res0 / self.tol), 1e-3)
            self.bar = tqdm(total=round(total, 2), desc=self.desc, unit="decade", leave=False,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} "
                                       "decades [{elapsed}<{remaining}{postfix}]")
        done = min(self.bar.total, round(max(0.0, math.log10(self.res0 / max(res, 1e-300))), 2))
        if done > self.bar.n:
            self.bar.update(done - self.bar.n)
        self.bar.set_postfix(it=it, residual=f"{res:.2e}", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class _Stall:
    """Stall detector: the run has stalled when its best residual has not fallen by a
    factor ``2`` within the last ``window`` iterations (and never when ``window`` is 0).

    Windows, measured on the Fig. 1 surface at tol 1e-10 (converging runs): the longest
    stretch without halving the best residual was 5-10 preconditioned CCG iterations
    (64^2 ... 512^2, two seeds) and 8, 14, 15, 31, 33 plain PK iterations at 64^2 ... 1024^2; 0-8 Newton steps (zeta = 1 ... 1e-4, 64^2 ... 512^2; the damped
    steps of a small-zeta start can raise the residual); 57-439 FIRE steps (64^2, 128^2,
    zeta down to 1e-3). The windows below leave a factor >= 2.5 over those. At 2048^2 the
    preconditioned CCG flattens at a residual of 1.5e-10 (round-off of the max-norm
    residual over 4M nodes), so tol 1e-10 stalls there. At an
    unreachable tol (1e-14) the residual flattens at round-off (1e-13 ... 1e-11) and
    never halves again, so the run stops one window after reaching round-off.
    """

    def __init__(self, window: int):
        self.window = int(window)
        self.best = math.inf
        self.it_best = 0

    def __call__(self, res: float, it: int) -> bool:
        if res < 0.5 * self.best or not math.isfinite(self.best):
            self.best, self.it_best = res, it
            return False
        return self.window > 0 and it - self.it_best >= self.window


def _stalled_message(stall: "_Stall", res: float) -> str:
    return (f"stalled: best residual {stall.best:.3e} (at iteration {stall.it_best}) did not "
            f"halve within {stall.window} iterations; last residual {res:.3e}")


# ----------------------------------------------------------------------------- CCG


#: CCG stall windows (iterations without halving the best residual): preconditioned
#: ``ccg`` (longest stretch measured 5-10, 64^2-512^2) and plain ``pk`` (8-33).
CCG_STALL_WINDOW = 50
PK_STALL_WINDOW = 200
#: ``ccg``: the preconditioner's FFT pair in single precision (see :func:`_ccg_hard`;
#: False restores the double-precision preconditioner of earlier versions)
SINGLE_PRECOND = True
#: ``ccg``: also ``r = G t`` of the step length in single precision, and then the exact
#: ``u = G p`` (double) after every step (False: ``r`` in double, ``u`` updated with it)
SINGLE_STEP = True
#: ``ccg`` with :data:`SINGLE_STEP`: between exact ``u = G p`` (double), ``u`` is updated by ``G dv`` of the step's
#: whole pressure change ``dv`` (projections and new contacts included) in single precision; its rounding is
#: relative to the increment, not to ``u``
INCREMENT_U32 = True
#: ... the rounding of one single-precision ``G dv`` relative to its largest value (a bound: measured median
#: 2.1-2.7e-7, at most 4.0e-7, over every increment of tol-1e-10 solves of Fig. 1 surfaces, 256^2-1024^2, seeds 1-2)
INCREMENT_ROUNDING = 2e-6
#: ... an exact ``u`` is taken again where the increments' rounding accumulated since the last one (the sum of
#: INCREMENT_ROUNDING max|G dv|) could exceed this share of the residual (in units of ``h_scale``, as the residual
#: measures gaps), after ``refresh`` increments, where the residual has not halved for INCREMENT_STALL iterations,
#: and before convergence is declared
#: (measured on a search since reverted: 1e-2 added 4-13 iterations at 512^2-1024^2, 1e-3 and 1e-4 none)
INCREMENT_SHARE = 1e-4
INCREMENT_STALL = 10
#: ... a step that neither projected a node nor added one changed ``p`` by ``-tau t`` alone: its increment is
#: ``-tau r`` with the step length's ``r = G t`` (single precision, the same rounding), and its FFT pair is saved
INCREMENT_REUSE_R = True
#: ... the increment applied by the next gap pass (True) or by a full pass of its own
FOLD_INCREMENT = True
#: ... folded only on grids of at most this many nodes: above, the fused gap pass (seven streams over arrays far
#: beyond the cache) was slower than the two passes it replaces. Measured in one process, the switch flipped between
#: solves, the solve's time less its transforms (its own timers), folded / own pass: 1.21 (seed 1) and 1.11 (seed 2)
#: at 4096^2 (2 pairs each: 16.2 s against 13.3 s and 14.3 against 12.9 s of 73-81 s; whole solves 1.01 and 1.06);
#: 0.98 and 1.02 at 2048^2, 0.89 and 1.02 at 1024^2 (6-8 pairs per seed). The same bits either way
FOLD_INCREMENT_MAX_NODES = 2048 * 2048
#: ``newton``: the inner CG's ``G d`` in single precision (the line search, ``u`` and the
#: residual in double)
SINGLE_NEWTON_CG = True
#: ... in a Newton step whose CG must reduce the predicted residual by no more than this
#: factor (float32 rounding of G d limits what the CG can reach; below it, double)
SINGLE_CG_MIN_FORCING = 1e-5
#: Newton stall window (Newton steps without halving the best residual).
NEWTON_STALL_STEPS = 20
#: FIRE stall window (steps without halving the best residual).
FIRE_STALL_WINDOW = 5000


def _full_contact_hard(h, p0, el):
    """Closed-form hard-wall solution when every node is in contact: the solid follows
    the surface, ``p = p0 + IFFT[(q E*/2) FFT(h)]``; valid (and exact) iff ``min p >= 0``.
    Returns the pressure or ``None``."""
    with np.errstate(over="ignore", invalid="ignore"):
        p = p0 + el.apply(el.K, h)
    if not np.all(np.isfinite(p)) or np.min(p) < 0.0:
        return None
    return p


def _ccg_hard(h, p0, el, tol, max_iter, progress, h_scale, lazy=8, refresh=50, lazy_frac=1e-4,
              stall_window=CCG_STALL_WINDOW, precond=False, single=None, p_start=None):
    """Polonsky & Keer (1999) constrained conjugate gradients on the pressures
    (Wear 231, 206, doi:10.1016/S0043-1648(99)00113-1).

    ``precond=True``: the search direction is built from ``z = K (g on the contact
    set)``, ``K = q E*/2`` the inverse of the Green's function (a Fourier-diagonal
    preconditioner; one more FFT pair per iteration), restricted to the contact set
    and shifted to zero mean there; ``beta = (g.z)_new / (g.z)_old``. Measured on the
    Fig. 1 surface: 221 -> 49 iterations at 1024^2 (296 -> 139 FFT pairs), 162 -> 44 at
    512^2. Used with ``lazy=1``: deferring the exact ``u`` (below) cost iterations
    with the preconditioner (91 instead of 49 at 1024^2 with ``lazy=8``).

    ``single`` (default :data:`SINGLE_PRECOND`): the preconditioner's FFT pair runs in
    single precision (``float32`` data and multiplier, :meth:`FFTWPair.apply_single`;
    the gap is written to it by :func:`~._kernels.pk_gap`, ``zbar`` and ``g.z`` are
    summed in double over the contact set by :func:`~._kernels.contact_sums`); with
    :data:`SINGLE_STEP` (default) also ``r = G t`` of the step length (from a float32
    copy of ``t`` that :func:`~._kernels.pk_direction` and :func:`~._kernels.pk_step`
    keep; ``rbar`` and ``t.r`` by :func:`~._kernels.contact_dot`), and then the exact
    ``u = G p`` in double after every step (``r`` no longer updates ``u``). The
    rounding (relative 1e-7) only perturbs the search direction and the step length:
    ``p``, ``u``, the step itself and every residual stay in double precision, so the
    answer is a converged solution to ``tol`` as before. Measured on the Fig. 1
    surface (seeds 1-3, tol 1e-8 and 1e-10, 256^2-2048^2): the same iteration counts,
    pressures within 7e-8 p0 of the double-precision solver's; a single pair costs 4.0
    ms against 6.2-7.3 ms at 1024^2; the preconditioner's pair in single precision
    gave 0.83-0.87x the time at 1024^2 and 2048^2, the step length's 0.94-0.98x more
    (docs/gfmd.md "Single-precision search").

    With :data:`INCREMENT_U32` (default) the double pair runs only now and then: the step's
    whole pressure change ``dv`` (projections and new contacts included, written by
    :func:`~._kernels.pk_step`) is transformed in single precision and
    ``u <- scale (u + G dv)`` (folded into the next gap pass, :func:`~._kernels.pk_gap`, on grids of at most
    :data:`FOLD_INCREMENT_MAX_NODES` nodes; a pass of its own above). Its rounding is
    relative to the increment, not to ``u`` (2-4e-7 of ``max |G dv|``), so the bound
    :data:`INCREMENT_ROUNDING` ``sum max |G dv|`` is tracked and an exact ``u`` taken
    where it could exceed :data:`INCREMENT_SHARE` of the residual, where the residual
    stalls, and always before convergence is declared: 3-6 exact pairs per solve on the
    Fig. 1 surfaces, the same iterations (docs/gfmd.md "The displacement by increments").

    ``u = G p`` is updated incrementally, ``u <- scale (u - tau G t)``; the part of a
    step that is not along ``t`` (projections onto ``p >= 0``, overlap fixes) is
    folded in by one exact ``u = G p`` every ``lazy``
    iterations, immediately when more than ``lazy_frac * N`` nodes changed in one
    step, and always before convergence is declared (every convergence decision uses
    an exact ``u``). Measured on the Fig. 1 surface at 1024^2: 296 instead of 367 FFT
    pairs (221 vs 211 iterations). Deferring large active-set changes stalls the
    search (seen on a sinusoid), hence the ``lazy_frac`` rule; as a further safeguard,
    if the residual has not halved for ``5 lazy`` iterations the solver falls back to
    an exact ``u`` every iteration. Grids below 512^2 always use the exact ``u``.

    Start: uniform ``p0`` (a coarse-grid start and a low-pass start were measured slower, see docs/gfmd.md).
    ``p_start`` (private, for ``benchmarks/gfmd_start.py``): a start pressure (``>= 0``, rescaled to the mean
    ``p0``); its contact set is where it is positive.
    Every FFT pair goes between work arrays of the cached FFT pair
    (:meth:`FFTWPair.apply_route`: no copy in or out), one full pass per iteration
    (the gap, which also applies the last increment of ``u``) and the rest on the contact
    set's sorted index list, with the pressure and the direction packed in its order (the
    full grid ``p`` is written only for an exact ``u`` and the answer; see :mod:`._kernels`).
    """
    n2 = h.size
    # work arrays of the cached FFT pair, transformed where they lie (no copies): the
    # pressure ``p``, ``u = G p`` (G p0 = 0: a uniform pressure does not deform), the
    # direction ``t`` and ``w``, which holds in turn the masked gap, K of it and r = G t;
    # in the single-precision search those three live in single arrays, and ``t`` and ``w``
    # hold the packed directions instead (below)
    single = bool(precond and (SINGLE_PRECOND if single is None else single))
    step32 = single and SINGLE_STEP
    incr = step32 and INCREMENT_U32
    # single-precision arrays: the preconditioned gap (0), the direction (1), r = G t (2) and, with incr, the step's
    # pressure change (3)
    n_single_arrays = (N_SINGLE_ARRAYS if incr else 3 if step32 else 1) if single else 0
    el.fft_planning_time += el.fft.make_work_arrays(N_WORK_ARRAYS, single=n_single_arrays)  # 0 once made
    p, u, t, w = (el.fft.work_array(k) for k in range(N_WORK_ARRAYS))
    t[...] = 0.0
    index = np.int32 if n2 < 2 ** 31 else np.int64  # 4 bytes per entry where they suffice
    idx_next = np.empty(n2, dtype=index)
    # the pressure and the direction on the contact set, packed in the order of idx (two lists each, swapped every
    # step); the full grid p is written from them only for an exact u = G p and the answer (kernels.scatter_contact).
    # The single-precision search leaves the work arrays t and w free: they hold the packed directions
    pc, pc_next = np.empty(n2), np.empty(n2)
    tc, tc_next = (t.ravel(), w.ravel()) if step32 else (np.zeros(n2), np.empty(n2))
    p_current = p_start is not None  # the full grid p holds the packed pressure
    if p_start is None:
        pc[...] = p0
        u[...] = 0.0
        c = np.ones(el.shape, dtype=np.bool_)  # the contact set p > 0, one byte per node
        idx = np.arange(n2, dtype=index)  # and its flat indices (two lists, swapped every step)
        nc = n2
    else:
        np.maximum(p_start, 0.0, out=p)
        p *= p0 / float(np.mean(p))
        el.fft.apply_route(el.Gn, p, u, dot=False)  # u = G p
        c = p > 0.0
        on = np.flatnonzero(c.ravel())
        nc = int(on.size)
        idx = np.empty(n2, dtype=index)
        idx[:nc] = on
        pc[:nc] = p.ravel()[on]
    gcon = np.empty(n2)  # the gap on the contact set, in the order of idx
    ol = np.empty(n2, dtype=index)  # overlaps (g < 0 off the set) and their gaps
    olg = np.empty(n2)
    psum = p0 * n2
    n_fft = 0 if p_start is None else 1  # (the start's u = G p)
    n_single = 0
    Kn = el.K / (el.n * el.n) if precond else None
    if single:
        Kn32 = Kn.astype(np.float32)
        w32 = el.fft.single_array()
    mdst = w32 if single else w
    t2 = t  # the direction on the full grid, the step length's FFT input: single precision (step32), else t
    dv32 = t2  # the step's pressure change (incr), else unused
    if step32:
        Gn32 = el.Gn.astype(np.float32)
        t2 = el.fft.single_array(1)
        r32 = el.fft.single_array(2)
        if incr:  # zero off the nodes a step visits
            dv32 = el.fft.single_array(3)
            dv32[...] = 0.0
        t2[...] = 0.0
    hist = []
    stamps = []
    tstart = time.perf_counter()
    delta = 0.0
    gold = 1.0
    converged = False
    pending = False  # u lacks G of the projections and overlap fixes
    since_exact = 0
    it = 0
    lazy_max_changes = max(4, int(lazy_frac * n2))
    if n2 < 512 * 512:
        lazy = 1  # FFTs are cheap on small grids: always exact u
    bar = _Progress(progress, "gfmd_ref ccg", tol)
    stall = _Stall(stall_window)
    stalled = False
    lost = None
    res = np.inf
    best, it_best = np.inf, 0
    u_rounding = 0.0  # the increments' rounding accumulated in u since the last exact u (bound)
    n_increments = 0

    def contact_mean(x):
        return kr.gather_sum(x, idx, nc) / nc if nc > 0 else 0.0

    # the last step's increment of u (u <- scale (u + G dv), G dv in dv32) waits for the next gap pass, which folds
    # it in (pk_gap's fold: one full pass instead of two)
    # (or, after a step that kept the contact set, u <- scale (u - tau r) with r = G t in r32)
    fold, fold_scale, fold_a, fold_gv = False, 1.0, 1.0, dv32
    fold_increments = FOLD_INCREMENT and n2 <= FOLD_INCREMENT_MAX_NODES
    n_reused = 0

    def residual():
        sg, gn, comp, pen, n_ol, gv_max = kr.pk_gap(u, h, pc, c, idx, nc, mdst, precond, gcon, ol, olg, fold_gv,
                                                    fold_a, fold_scale, fold)
        load = abs(psum / n2 - p0) / p0
        return sg, gn, n_ol, max(load, comp / (p0 * h_scale), pen / h_scale), gv_max

    while True:
        sg, gn, n_ol, res, gv_max = residual()
        if fold:
            u_rounding = fold_scale * (u_rounding + INCREMENT_ROUNDING * abs(fold_a) * gv_max)
            fold = False
        if (res < tol or it >= max_iter) and (pending or since_exact > 0):
            kr.scatter_contact(pc, idx, nc, p)
            p_current = True
            el.fft.apply_route(el.Gn, p, u, dot=False)
            n_fft += 1
            pending = False
            since_exact = 0
            sg, gn, n_ol, res, _ = residual()
            u_rounding = 0.0
        hist.append(res)
        stamps.append((it, time.perf_counter() - tstart))
        bar.update(res, it)
        if res < tol:
            converged = True
            break
        if it >= max_iter:
            break
        if stall(res, it):
            stalled = True
            break
        if res < 0.5 * best:
            best, it_best = res, it
        elif lazy > 1 and it - it_best > 5 * lazy:
            lazy = 1  # stagnation safeguard: fall back to exact u every iteration
            lazy_max_changes = 0
            delta = 0.0  # and restart the conjugate directions
        if precond:
            # masked g -> z = K (masked g), in place; g.z over the contact set
            if single:
                el.fft.apply_single(Kn32)
                n_single += 1
                z = w32
                zsum, sgz = kr.contact_sums(w32, gcon, idx, nc)
                zbar = zsum / nc if nc > 0 else 0.0
            else:
                z = w
                sgz = el.fft.apply_route(Kn, w, w)  # sum_c g z = (masked g).z by Parseval
                zbar = contact_mean(w)
            n_fft += 1
            gz = sgz - zbar * sg  # sum_c g (z - zbar), the preconditioned residual norm
            beta = delta * gz / gold if gold > 0.0 else 0.0
            st, sgt = kr.pk_direction(z, False, gcon, idx, nc, tc, zbar, beta, t2)
            gold = gz
        else:
            beta = delta * gn / gold if gold > 0.0 else 0.0
            st, sgt = kr.pk_direction(w, True, gcon, idx, nc, tc, 0.0, beta, t2)
            gold = gn
        if step32:
            el.fft.apply_single(Gn32, 1, 2)  # r32 = G t in single precision (tau only)
            n_fft += 1
            n_single += 1
            rsum, srt = kr.contact_dot(r32, tc, idx, nc)
            rbar = rsum / nc if nc > 0 else 0.0
        else:
            srt = el.fft.apply_route(el.Gn, t, w)  # w = r = G t; sum_c r t = t.r (Parseval)
            n_fft += 1
            rbar = contact_mean(w)
        den = srt - rbar * st  # sum_c (r - rbar) t
        tau = sgt / den if den != 0 else 0.0
        # the increment's G dv instead of an exact u, unless the rounding u may have gathered is no longer far below
        # the residual, or the residual stalls, or refresh increments ran
        use_incr = incr and not (u_rounding > INCREMENT_SHARE * res * h_scale or since_exact + 1 >= refresh
                                 or it - it_best > INCREMENT_STALL)
        nc_before = nc
        nproj, psum, nc = kr.pk_step(pc, c, tc, idx, nc, ol, olg, n_ol, tau, idx_next, pc_next, tc_next, t2, dv32,
                                     use_incr)
        p_current = False
        idx, idx_next = idx_next, idx
        pc, pc_next = pc_next, pc
        tc, tc_next = tc_next, tc
        if not psum > 0.0:  # the step removed every contact: no load can be restored (never seen)
            lost = f"a step removed every contact (sum p = {psum:g} after step {it + 1})"
            break
        scale = p0 * n2 / psum
        delta = 0.0 if n_ol > 0 else 1.0
        it += 1
        since_exact += 1
        if nproj or n_ol:
            pending = True
        if use_incr:  # u <- scale (u + G dv), G dv in single precision (in place on dv, which the next gap pass
            # folds into u and zeroes)
            n_increments += 1
            if INCREMENT_REUSE_R and nproj == 0 and nc == nc_before:  # the set kept: dv = -tau t, G dv = -tau r
                kr.zero_at(dv32, idx, nc)
                fold_gv, fold_a = r32, -tau
                n_reused += 1
            else:
                el.fft.apply_single(Gn32, 3)
                n_fft += 1
                n_single += 1
                fold_gv, fold_a = dv32, 1.0
            psum = kr.pk_rescale(pc, nc, scale, u, u, 0.0, True)  # the pressure now, u in the next gap pass
            if fold_increments:
                fold, fold_scale = True, scale
            else:
                gv_max = kr.apply_increment(u, fold_gv, fold_a, scale)
                u_rounding = scale * (u_rounding + INCREMENT_ROUNDING * abs(fold_a) * gv_max)
            pending = False  # u has every change, up to the increments' rounding (since_exact counts them)
            continue
        big = nproj + n_ol > lazy_max_changes
        exact = step32 or (pending and (it % lazy == 0 or big)) or since_exact >= refresh
        psum = kr.pk_rescale(pc, nc, scale, u, w, tau, exact)  # not exact: u <- scale (u - tau r)
        if exact:
            kr.scatter_contact(pc, idx, nc, p)
            p_current = True
            el.fft.apply_route(el.Gn, p, u, dot=False)
            n_fft += 1
            pending = False
            since_exact = 0
            u_rounding = 0.0
    bar.close()
    if not p_current:  # the answer's full grid, unless the last exact u wrote it
        kr.scatter_contact(pc, idx, nc, p)
    # displacement: z0 such that the gap vanishes on the contact set
    mask = p > 0
    z0 = float(np.mean((h - u)[mask])) if np.any(mask) else float(np.max(h - u))
    disp = u + z0
    gap = disp - h
    return dict(
        pressure=p.copy(),  # p is a work array of the cached FFT pair: the next solve reuses it
        gap=gap,
        displacement=disp,
        converged=converged,
        iterations=it,
        residual=res,
        history=np.asarray(hist),
        stop=("converged" if converged else lost if lost else _stalled_message(stall, res) if stalled
              else "max_iter"),
        info=dict(h_scale=h_scale, fft_pairs=n_fft, fft_pairs_single=n_single,
                  u_increments=n_increments, u_increments_reusing_r=n_reused,
                  u_increments_folded=bool(incr and fold_increments),
                  history_stamps=np.asarray(stamps)),
    )


# ----------------------------------------------------------------------------- dual Newton


def _log_ratio(p: np.ndarray, p0: float, out: np.ndarray) -> np.ndarray:
    """``out = log(p/p0)`` by numpy (vectorized; a compiled ``math.log`` loop took 4.6 ms
    against 1.7 ms per 1024^2)."""
    np.divide(p, p0, out=out)
    return np.log(out, out=out)


def _z0_residual(u: np.ndarray, h: np.ndarray, p: np.ndarray, p0: float, zeta: float,
                 scratch: np.ndarray, keep: np.ndarray | None = None) -> tuple:
    """``(z0, residual)`` of the exponential wall with one (vectorized) exponential per
    node: ``z0 = zeta log(mean(exp(-(u - h)/zeta)))`` (log-sum-exp, as
    :func:`._kernels.exp_log_mean`) and ``max |p0 exp(-(z0 + u - h)/zeta) - p| / p0``
    (:func:`._kernels.exp_sum_residual`); ``scratch`` holds the exponentials, ``keep``
    (a boolean array of the same shape, made if None) where they are not ``+0``."""
    if keep is None:
        keep = np.empty(u.shape, dtype=np.bool_)
    m = kr.exp_exponents(u, h, zeta, scratch, keep)
    np.exp(scratch, out=scratch, where=keep)
    s, res = kr.exp_sum_residual(scratch, p, p0)
    return zeta * (m + math.log(s / h.size)), res


def _newton_exp(h, p0, zeta, el, tol, max_iter, progress, p_init=None, iters0=0, hist0=(),
                stall_steps=NEWTON_STALL_STEPS):
    """Newton-CG on the dual (pressure) energy of the exponential wall

    ``Phi(p) = mean(p u/2 - p h + zeta p log(p/p0))``, ``u = G p``, ``mean(p) = p0``,

    whose minimiser is the equilibrium pressure (``p = p0 exp(-(z0 + u - h)/zeta)``).
    The Hessian ``G + diag(zeta/p)`` is inverted by projected CG (constraint
    ``sum dp = 0``) with the diagonal preconditioner ``1/(G_ii + zeta/p)``; steps
    that decrease ``p`` are taken multiplicatively (``p exp(dp/p)``) so ``p`` stays
    positive, with an Armijo backtracking on ``Phi``.

    Work (thirty-fifth session, docs/gfmd.md "The exponential wall's Newton-CG"): the
    state lives in the FFT pair's work arrays; a CG iteration is one FFT pair and three
    fused passes (:func:`~._kernels.ncg_update`, :func:`~._kernels.ncg_shift`,
    :func:`~._kernels.ncg_direction`); ``G d`` runs in single precision
    (:data:`SINGLE_NEWTON_CG`) in every Newton step whose forcing asks the CG for no more
    than :data:`SINGLE_CG_MIN_FORCING` of the predicted residual (else in double); the
    line search, ``u = G p`` and the residual (:func:`_z0_residual`, one vectorized
    exponential per node; the logarithms by numpy too) stay in double. The line search
    judges by the force residual where the energy change is below the round-off of the
    energy's terms (their mean magnitude, which exceeds ``|Phi|`` by orders near the
    solution). Measured on the Fig. 1 surface at 1024^2: the same iterations as before,
    0.63-0.73x the time.
    """
    n2 = h.size
    pmin = max(p0 * 1e-300, 1e-300)
    # work arrays of the cached FFT pair, transformed where they lie: the pressure and
    # u = G p, and the CG direction d and G d, which the line search reuses for the trial
    # pressure and its u (the pairs swap names when a step is accepted)
    el.fft_planning_time += el.fft.make_work_arrays(N_WORK_ARRAYS,
                                                    single=N_SINGLE_ARRAYS if SINGLE_NEWTON_CG else 0)
    p, u, d, gd = (el.fft.work_array(k) for k in range(N_WORK_ARRAYS))
    if SINGLE_NEWTON_CG:  # the CG's G d in single precision: d's float32 copy -> G d
        d32, gd32 = el.fft.single_array(1), el.fft.single_array(2)
        Gn32 = el.Gn.astype(np.float32)
    if p_init is None:
        p[...] = p0
    else:
        np.maximum(p_init, pmin, out=p)
    p *= p0 / p.mean()
    el.fft.apply_route(el.Gn, p, u, dot=False)
    grad = np.empty(el.shape)
    minv = np.empty(el.shape)
    wdiag = np.empty(el.shape)
    x = np.empty(el.shape)
    r = np.empty(el.shape)
    scratch = np.empty(el.shape)
    keep = np.empty(el.shape, dtype=np.bool_)  # where the wall's exponentials are not +0
    lp = np.empty(el.shape)
    hist = list(hist0)
    stamps = []
    tstart = time.perf_counter()
    it = iters0
    newton = 0
    cg_total = 0
    n_single = 0
    converged = False
    stop = "max_iter"
    bar = _Progress(progress, "gfmd_ref newton", tol)
    stall = _Stall(stall_steps)
    _log_ratio(p, p0, lp)  # then kept by every accepted step: its trial's energy leaves log(ptry/p0) in lp
    while True:
        E, E_scale = kr.dual_gradient(u, h, p, lp, zeta, grad)
        z0, res = _z0_residual(u, h, p, p0, zeta, scratch, keep)
        hist.append(res)
        stamps.append((it, time.perf_counter() - tstart))
        bar.update(res, it)
        if res < tol:
            converged = True
            stop = "converged"
            break
        if it >= max_iter:
            break
        if stall(res, newton):
            stop = _stalled_message(stall, res).replace("iterations", "Newton steps")
            stop = stop.replace("(at iteration", "(at Newton step")
            break
        # --- inexact Newton direction by projected PCG on (G + diag(zeta/p)) x = -grad,
        # three fused passes and one FFT pair per iteration (kernels ncg_*)
        np.divide(zeta, p, out=wdiag)
        np.add(wdiag, el.g_diag, out=minv)
        np.divide(1.0, minv, out=minv)
        sum_minv = float(np.sum(minv))
        sum_p = float(np.sum(p))
        target = max(0.1 * res * min(1.0, res), 0.25 * tol)
        x[...] = 0.0
        np.negative(grad, out=r)
        rz, pred0 = kr.ncg_shift(r, minv, p, float(np.dot(minv.ravel(), r.ravel())) / sum_minv,
                                 float(np.dot(p.ravel(), r.ravel())) / sum_p)
        # single precision only where the forcing asks for no more than it can deliver
        single = SINGLE_NEWTON_CG and target >= SINGLE_CG_MIN_FORCING * pred0 / (zeta * p0)
        d[...] = 0.0
        dwd = kr.ncg_direction(d, r, minv, wdiag, 0.0, d32 if single else d)
        for _ in range(2000):
            if single:
                dAd = el.fft.apply_single(Gn32, 1, 2, dot=True) + dwd
                n_single += 1
            else:
                dAd = el.fft.apply_route(el.Gn, d, gd) + dwd  # d.G d by Parseval, + d.diag d
            it += 1
            cg_total += 1
            if dAd <= 0:
                break
            a = rz / dAd
            sm, sp = kr.ncg_update(x, r, d, gd32 if single else gd, wdiag, minv, p, a)
            rz_new, pred = kr.ncg_shift(r, minv, p, sm / sum_minv, sp / sum_p)
            if it >= max_iter or pred / (zeta * p0) <= target:
                break
            dwd = kr.ncg_direction(d, r, minv, wdiag, rz_new / rz, d32 if single else d)
            rz = rz_new
        # --- line search: the trial pressure and its u in the direction's work arrays
        ptry, utry = d, gd
        slope = float(np.vdot(grad, x)) / n2
        alpha = 1.0
        accepted = False
        for _ls in range(30):
            kr.dual_step(p, x, alpha, p0, pmin, ptry)
            el.fft.apply_route(el.Gn, ptry, utry, dot=False)
            it += 1
            Et, _ = kr.dual_energy(utry, h, ptry, _log_ratio(ptry, p0, lp), zeta)
            if Et <= E + 1e-4 * alpha * slope:
                accepted = True
                break
            if abs(Et - E) <= 1e-11 * max(abs(E), E_scale):
                # energy differences at round-off (of the energy's terms, whose magnitude
                # E_scale can exceed |E| by 1e4 near the solution): judge by the force
                # residual instead
                rt = _z0_residual(utry, h, ptry, p0, zeta, scratch, keep)[1]
                if rt < (1.0 - 1e-4 * alpha) * res:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            stop = (f"stalled: the line search found no decrease of the dual energy in 30 "
                    f"halvings (round-off level); residual {res:.3e}")
            break
        p, d = ptry, p
        u, gd = utry, u
        # lp already holds log(p/p0) of the accepted trial (its energy computed it last)
        newton += 1
    bar.close()
    disp = u + z0  # z0 of this u: every exit leaves the loop after computing it, u unchanged since
    return dict(
        pressure=p.copy(),  # p is a work array of the cached FFT pair: the next solve reuses it
        gap=disp - h,
        displacement=disp,
        converged=converged,
        iterations=it,
        residual=res,
        history=np.asarray(hist),
        stop=stop,
        info=dict(newton_steps=newton, cg_iterations=cg_total, fft_pairs_single=n_single,
                  history_stamps=np.asarray(stamps)),
    )


# ----------------------------------------------------------------------------- FIRE GFMD


def _fire(h, p0, interaction, el, tol, max_iter, progress, h_scale, stall_window=FIRE_STALL_WINDOW):
    """Mass-weighted FIRE dynamics of the Fourier modes of the solid surface ``z``.

    Mode masses ``m(q) = q E*/2 + kappa`` (every elastic mode has the same
    frequency; ``kappa`` = mean interaction stiffness ``p0/zeta`` for the exponential
    wall, ``q_1 E*/2`` for the hard wall and as a floor), FIRE velocity mixing in the
    mass-weighted metric (Bitzek et al. 2006). The hard wall is a projection
    ``z >= h`` with the inward velocity of clipped nodes removed.
    """
    n = el.n
    n2 = n * n
    hard = isinstance(interaction, HardWall)
    zeta = None if hard else interaction.zeta
    kfloor = el.q1 * el.E_star / 2.0
    kappa = kfloor if hard else max(p0 / zeta, kfloor)
    m = el.K + kappa
    K = el.K
    w = el.w
    kbar = float(np.sum(w * K)) / n2 + kappa
    # start: flat surface touching the highest point (hard) / carrying p0 (exp)
    if hard:
        z = np.full(el.shape, float(h.max()))
    else:
        z = np.full(el.shape, kr.exp_log_mean(np.zeros(el.shape), h, zeta))
    Z = el.rfft(z)
    V = np.zeros_like(Z)
    sig = np.empty(el.shape)
    freal = np.empty(el.shape)
    contact = np.zeros(el.shape, dtype=np.bool_)
    N_MIN, F_INC, F_DEC, A0, F_A = 5, 1.1, 0.5, 0.1, 0.99
    dt_max = 0.5
    dt = 0.1
    alpha = A0
    npos = 0
    hist = []
    stamps = []
    tstart = time.perf_counter()
    it = 0
    converged = False
    res = np.inf
    stop = "max_iter"
    bar = _Progress(progress, "gfmd_ref fire", tol)
    stall = _Stall(stall_window)
    while True:
        # forces on the modes (unnormalised rfft units)
        if hard:
            pel = p0 + el.irfft(K * Z)
            fr, s = kr.hard_force(contact, pel, freal)
            load = abs(s / n2 - p0) / p0
            res = max(fr / p0, load)
            F = el.rfft(freal)
        else:
            smax = 0.0
            kr.exp_pressure(z, h, p0, zeta, sig)
            smax = float(sig.max())
            F = el.rfft(sig)
            F -= K * Z
            F[0, 0] -= p0 * n2
            fr = el.irfft(F)
            res = float(np.max(np.abs(fr))) / p0
            dt_max = min(0.5, 0.9 / math.sqrt(1.0 + (smax / zeta) / kbar))
            dt = min(dt, dt_max)
        hist.append(res)
        stamps.append((it, time.perf_counter() - tstart))
        if it % 5 == 0:
            bar.update(res, it)
        if res < tol:
            converged = True
            stop = "converged"
            break
        if it >= max_iter:
            break
        if not math.isfinite(res):
            stop = f"diverged: non-finite residual {res} at step {it}"
            break
        if stall(res, it):
            stop = _stalled_message(stall, res)
            break
        P = float(np.sum(w * (F.real * V.real + F.imag * V.imag)))
        if P > 0:
            vn = math.sqrt(float(np.sum(w * m * (V.real**2 + V.imag**2))))
            fn = math.sqrt(float(np.sum(w * (F.real**2 + F.imag**2) / m)))
            V *= 1.0 - alpha
            if fn > 0:
                V += (alpha * vn / fn) * (F / m)
            npos += 1
            if npos > N_MIN:
                dt = min(dt * F_INC, dt_max)
                alpha *= F_A
        else:
            V[...] = 0.0
            dt *= F_DEC
            alpha = A0
            npos = 0
        V += (dt / m) * F
        Z += dt * V
        z = el.irfft(Z)
        if hard:
            v = el.irfft(V)
            kr.project_active(z, h, v, pel, contact)
            Z = el.rfft(z)
            V = el.rfft(v)
        it += 1
    bar.close()
    if hard:
        pel = p0 + el.irfft(K * Z)
        p = np.where(contact & (pel > 0), pel, 0.0)
        gap = np.where(contact, 0.0, z - h)
        z = np.where(contact, h, z)
    else:
        kr.exp_pressure(z, h, p0, zeta, sig)
        p = sig.copy()
        gap = z - h
    s = p.mean()
    if s > 0:
        p *= p0 / s
    return dict(
        pressure=p,
        gap=gap,
        displacement=z,
        converged=converged,
        iterations=it,
        residual=res,
        history=np.asarray(hist),
        stop=stop,
        info=dict(
            load_rescale=float(p0 / s) if s > 0 else float("nan"),
            final_dt=dt,
            history_stamps=np.asarray(stamps),
        ),
    )


# ----------------------------------------------------------------------------- driver


def _check_interaction(interaction):
    if not isinstance(interaction, (HardWall, ExponentialRepulsion)):
        raise ValueError(
            "interaction must be gfmd_ref.HardWall() or gfmd_ref.ExponentialRepulsion(zeta); "
            f"got {interaction!r}"
        )
    return type(interaction).__name__


def default_max_iter(n: int, interaction, method: str) -> int:
    if method == "fire":
        base = 20000
        if isinstance(interaction, ExponentialRepulsion):
            base = 100000
        return base
    return 5000 + 20 * n


def solve_contact(
    heights,
    *,
    length,
    E_star,
    mean_pressure,
    interaction,
    tol: float = 1e-8,
    max_iter: int | None = None,
    method: str = "auto",
    progress: bool = False,
    warm_start: bool | None = None,
    threads: int | None = None,
) -> ContactResult:
    """Equilibrium of an elastic half-space pressed on a rigid periodic rough surface.

    Units: any consistent system. Lengths (``heights``, ``length``, ``zeta``, and the
    returned ``gap``/``displacement``) share one length unit; pressures (``E_star``,
    ``mean_pressure``, the returned ``pressure``) share one pressure unit (e.g. the
    paper's Fig. 1 scene: lengths in grid spacings, ``E* = 8/3``, ``p0 = 0.004`` in units
    of the shear modulus). Only ratios matter: the pressure field scales with ``p0``,
    the displacements with ``p0 / E*`` times a length.

    Parameters
    ----------
    heights : (n, n) array
        Rigid surface heights [length] on one ``L x L`` periodic cell (square grids only;
        any ``n >= 2``, not only powers of two). Contact happens where ``h`` is high.
    length : float
        Cell side ``L`` [length] (> 0); the grid spacing is ``L / n``.
    E_star : float
        Contact modulus ``E* = E/(1 - nu^2)`` [pressure] (> 0).
    mean_pressure : float
        Imposed mean pressure ``p0`` [pressure] (> 0), load control.
    interaction : HardWall or ExponentialRepulsion
        ``ExponentialRepulsion(zeta)``: ``zeta`` [length].
    tol : float
        Convergence tolerance on the residual [dimensionless], relative to ``p0``
        (see module doc).
    max_iter : int, optional
        Cap on operator applications (FFT pairs; default depends on method and size).
    method : {"auto", "ccg", "pk", "newton", "fire"}
        ``"ccg"``: Polonsky-Keer constrained conjugate gradients with a Fourier-diagonal
        preconditioner (``q E*/2``, the inverse of the Green's function; hard wall only;
        4x fewer iterations than ``"pk"`` at 1024^2); ``"pk"``: the same without the
        preconditioner (the algorithm of Tamaas' ``PolonskyKeerRey``);
        ``"newton"``: dual Newton-CG (exponential wall only); ``"fire"``: GFMD with
        mass-weighted FIRE (both). ``"auto"`` picks ``ccg`` / ``newton``.
        With ``ccg``/``pk``, a load high enough for full contact is answered by the closed form
        ``p = p0 + IFFT[(q E*/2) FFT(h)]`` (exact when it is ``>= 0`` everywhere;
        ``info["closed_form"] = True``, zero iterations).
    progress : bool
        Show a tqdm progress bar in decades of residual reduction (from the first
        residual down to ``tol``).
    warm_start : bool, optional
        Exponential wall with ``newton``: start from the hard-wall (CCG) solution
        instead of the uniform pressure ``p0``. Default False: measured on the Fig. 1
        surface, the cold start is faster for every zeta from 4 down to 0.001.
    threads : int, optional
        FFT threads (default ``gfmd_ref._fft.DEFAULT_THREADS`` = 1, the faster choice
        measured on the loaded 2-core development machine). The answer does not depend
        on it beyond round-off.

    Returns
    -------
    ContactResult
        ``pressure`` [pressure], ``gap`` and ``displacement`` [length]. Warns
        :class:`ConvergenceWarning` (and has ``converged=False``) if the tolerance was
        not reached: ``max_iter`` exhausted or the residual stalled (it did not halve
        within a window of iterations, e.g. a tol below round-off); ``message`` gives
        the residual reached, the iterations and the reason (``info["stop"]``).

    Raises
    ------
    ValueError
        Bad input, naming the parameter; also when the elastic response of the
        exponential wall is below double-precision resolution of ``p0`` (round-off
        floor of the residual ``eps p0 / (E* q1 zeta) > 1e-3``, ``q1 = 2 pi / L``:
        ``E_star`` far too small for ``mean_pressure``).
    """
    t0 = time.perf_counter()
    h = check_heights(heights)
    length = check_positive("length", length)
    E_star = check_positive("E_star", E_star)
    p0 = check_positive("mean_pressure", mean_pressure)
    tol = check_positive("tol", tol)
    threads = check_threads(threads)
    kind = _check_interaction(interaction)
    allowed = ("auto",) + METHODS[kind]
    if not isinstance(method, str) or method not in allowed:
        raise ValueError(f"method must be one of {allowed} for {kind}; got {method!r}")
    if method == "auto":
        method = METHODS[kind][0]
    n = h.shape[0]
    if max_iter is None:
        max_iter = default_max_iter(n, interaction, method)
    max_iter = check_int("max_iter", max_iter, minimum=1)
    q1 = 2.0 * math.pi / length
    if isinstance(interaction, ExponentialRepulsion):
        # u = G p carries an absolute error ~ eps p0 / (E* q1), i.e. a force residual
        # floor ~ eps p0 / (E* q1 zeta) relative to p0 (measured within a factor 4 of
        # the residual reached at tol 1e-18, E* = 1e-2 ... 1e-10, 64^2). Where even 1e-3
        # is out of reach the problem is not computable in double precision: refuse it.
        # Below that, an unreachable tol ends by stall detection (converged=False).
        floor = 2.2e-16 * (p0 / E_star) / (q1 * interaction.zeta)
        if not floor < EXP_FLOOR_LIMIT:
            need = 2.2e-16 * p0 / (q1 * interaction.zeta * EXP_FLOOR_LIMIT)
            raise ValueError(
                f"E_star={E_star!r} is too small for mean_pressure={p0!r} and zeta="
                f"{interaction.zeta!r}: the elastic response is below double precision "
                f"(force-residual floor {floor:.1e} p0); need E_star > {need:.1e}"
            )
    el = _Elastic(n, length, E_star, threads)
    fft_t0, mult_t0 = el.fft.transform_seconds, el.fft.multiply_seconds  # (the pair may be cached: its totals)
    hs = float(np.std(h))
    h_scale = hs if hs > 0 else length

    closed = None
    if method in ("ccg", "pk"):
        closed = _full_contact_hard(h, p0, el)
    if closed is not None:
        load = abs(float(np.mean(closed)) - p0) / p0
        out = dict(pressure=closed, gap=np.zeros_like(h), displacement=h.copy(),
                   converged=load < tol, iterations=0, residual=load,
                   history=np.array([load]), stop="converged" if load < tol else "max_iter",
                   info=dict(h_scale=h_scale, fft_pairs=1, closed_form=True,
                             history_stamps=np.array([[0.0, time.perf_counter() - t0]])))
    elif method in ("ccg", "pk"):
        if method == "ccg":
            out = _ccg_hard(h, p0, el, tol, max_iter, progress, h_scale, precond=True, lazy=1)
        else:
            out = _ccg_hard(h, p0, el, tol, max_iter, progress, h_scale, precond=False,
                            stall_window=PK_STALL_WINDOW)
        out["info"]["closed_form"] = False
    elif method == "fire":
        out = _fire(h, p0, interaction, el, tol, max_iter, progress, h_scale)
    else:
        zeta = interaction.zeta
        if warm_start is None:
            warm_start = False  # measured: the cold start is faster for every zeta
        p_init = None
        it0 = 0
        hist0 = ()
        tw = time.perf_counter()
        if warm_start:
            hw = _ccg_hard(h, p0, el, max(1e-6, tol), max_iter, False, h_scale)
            it0 = hw["iterations"]
            g = np.maximum(hw["gap"], 0.0)
            p_init = np.where(
                hw["pressure"] > 0, hw["pressure"], p0 * np.exp(-np.minimum(g / zeta, 740.0))
            )
        tw = time.perf_counter() - tw
        out = _newton_exp(h, p0, zeta, el, tol, max_iter, progress, p_init, it0, hist0)
        if out["info"]["history_stamps"].size:
            out["info"]["history_stamps"][:, 1] += tw
        out["info"]["warm_start"] = bool(warm_start)
        out["info"]["warm_start_iterations"] = it0

    p = out["pressure"]
    if isinstance(interaction, HardWall):
        thr = 0.0
        cf = float(np.count_nonzero(p > 0)) / p.size
    else:
        thr = EXP_CONTACT_THRESHOLD * p0
        cf = float(np.count_nonzero(p > thr)) / p.size
    wall = time.perf_counter() - t0
    if out["converged"]:
        how = "closed form (full contact)" if out["info"].get("closed_form") else method
        msg = (
            f"converged: residual {out['residual']:.3e} < tol {tol:.1e} "
            f"after {out['iterations']} iterations ({how})"
        )
    else:
        reason = out["stop"]
        if reason == "max_iter":
            reason = f"max_iter={max_iter} reached"
        msg = (
            f"NOT converged: residual {out['residual']:.3e} > tol {tol:.1e} "
            f"after {out['iterations']} iterations ({method}; {reason})"
        )
        warnings.warn(msg, ConvergenceWarning, stacklevel=2)
    return ContactResult(
        pressure=p,
        gap=out["gap"],
        displacement=out["displacement"],
        contact_fraction=cf,
        converged=bool(out["converged"]),
        iterations=int(out["iterations"]),
        residual=float(out["residual"]),
        wall_time=wall,
        method=method,
        message=msg,
        residual_history=out["history"],
        interaction=interaction,
        mean_pressure=p0,
        E_star=E_star,
        length=length,
        tol=tol,
        contact_threshold=thr,
        info={**out["info"], "stop": out["stop"], "fft": el.fft.name,
              "fft_threads": el.fft.threads, "fft_planning_time": el.fft_planning_time,
              "fft_seconds": el.fft.transform_seconds - fft_t0,
              "multiply_seconds": el.fft.multiply_seconds - mult_t0},
    )
