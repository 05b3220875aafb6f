"""gfmd_ref: Green's-function molecular dynamics reference solver.

A standalone (numpy, scipy, numba) solver for an elastic half-space pressed on a
rigid, periodic rough surface, with hard-wall or exponential repulsion. It never
imports :mod:`diffusion_pr`.
"""
