"""Names the command line needs before anything heavy is imported (``phc --help`` must
not import sympy, scipy or pydantic)."""

SOLVER_NAMES = ("ida", "midpoint", "discrete_gradient", "midpoint4")
"""The integrators, in the order ``--help`` lists them (the model schema's `solver`)."""
