"""diffusion_pr: pressure distributions in rough elastic contacts.

Müser's field theory of rough contact (Phys. Rev. Lett. 100, 055504 (2008),
doi:10.1103/PhysRevLett.100.055504): Persson's mirror Gaussian as the leading
order, the second-order cumulant ``G1(q)`` for exponentially repulsive walls, and
the magnification-dependent drift-diffusion (Fokker-Planck) equation for
``Pr(p, eta)``.
"""
