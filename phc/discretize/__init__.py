"""Discretization of distributed components (stage "elaborate"): the one-dimensional finite
element spaces and their sparse matrices (:mod:`phc.discretize.fem1d`) that the lowerers of
strings, beams, modal truncations and ``pde1d`` components (:mod:`phc.library`) build on."""
