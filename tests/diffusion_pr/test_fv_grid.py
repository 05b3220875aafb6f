"""The graded nested grids (diffusion_pr/solvers/fv/grid.py): Phi^-1 and nesting."""
from __future__ import annotations

import numpy as np
import pytest

from diffusion_pr.solvers.fv import grid
from diffusion_pr.solvers.fv.grid import GridSpec, edges_for, knot_indices

SPECS = [
    # a floor 16 decades down with a cutoff knot (Fig. 1 scene), a wall at 0 with a p0 grading, no grading
    GridSpec(p_wall=4e-16, p_max=0.104, knots=(4e-9, 0.0027, 0.004), scale=0.009, c_wall=0.6, c_0=0.0, w0=0.009,
             p0=0.004),
    GridSpec(p_wall=0.0, p_max=6.0, knots=(1.0,), scale=0.05, c_wall=0.0, c_0=1.0, w0=1e-3, p0=1.0),
    GridSpec(p_wall=0.0, p_max=8.0, knots=(1.0,), scale=1.0, c_wall=0.0, c_0=0.0, w0=1.0, p0=1.0),
]


@pytest.mark.parametrize("spec", SPECS)
def test_inverse_of_the_monitor_function_to_round_off(spec):
    """Phi(Phi^-1(t)) = t to 1e-13 (Newton path), and the safeguarded fallback lands on the same points."""
    a, b = spec.p_wall, spec.p_max
    ph = spec.phi(np.array([a, b]))
    targets = np.linspace(ph[0], ph[1], 2001)
    x = grid._invert(spec, targets, a, b)
    assert np.all(np.diff(x) > 0) and x[0] >= a and x[-1] <= b
    assert np.max(np.abs(spec.phi(x) - targets) / np.maximum(np.abs(targets), 1.0)) < 1e-13
    tol = 1e-14 * np.maximum(np.abs(targets), 1.0)
    start = np.interp(targets, *grid._table(spec, a, b)[::-1])
    safe = grid._invert_safe(spec, targets, start, a, b, tol)
    assert np.max(np.abs(safe - x) / np.maximum(x, 1e-300)) < 1e-12


@pytest.mark.parametrize("spec", SPECS)
def test_doubled_grid_nests_bit_for_bit(spec):
    """The grid of 2 idx (factor 4) has the grid of idx (factor 4) as every other edge, to the last bit:
    the engine's doubling levels reuse the solutions on those grids."""
    idx = knot_indices(spec, 97)
    fine = edges_for(spec, idx, 4)
    finer = edges_for(spec, 2 * idx, 4)
    assert np.array_equal(finer[::2], fine)
    assert np.array_equal(edges_for(spec, idx, 2), fine[::2])
