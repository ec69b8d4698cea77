"""Names the command line needs before anything heavy is imported (``phc --help`` must
not import sympy, scipy or pydantic)."""

SOLVER_NAMES = ("ida", "midpoint", "discrete_gradient", "midpoint4")
"""The integrators, in the order ``--help`` lists them (the model schema's `solver`)."""

PEER_SOLVER_NAMES = ("scipy_Radau", "scipy_BDF", "scipy_DOP853")
"""scipy's methods given the same residual (:mod:`phc.study.ode_form`), which ``phc bench`` sweeps
beside phc's solvers when asked for (``--solver``, a scene's ``bench.solvers``)."""

RUN_LIMITS: dict[str, tuple[str, float, float]] = {
    "t_end": ("positive", 0, float("inf")),
    "n_out": ("count", 2, 10_000_000),
    "rtol": ("fraction", 0, 1),
    "atol": ("positive", 0, float("inf")),
    "step": ("positive", 0, float("inf")),
    "max_steps": ("count", 1, 2 ** 31 - 1),
    "max_order": ("count", 1, 5),
}
"""The numeric run options' ranges, by name: ``(kind, low, high)`` with kind ``positive``
(finite, ``low < x <= high``), ``fraction`` (``low < x < high``) or ``count`` (a whole
number in ``[low, high]``). The one definition that :class:`phc.options.RunOptions` (and so
the model's `simulation` section and a scene's `accuracy`), the command line's options
and :func:`phc.simulate` all check against. `max_steps` is at most 2³¹ − 1: IDA keeps it in
a C long (32 bits on some platforms)."""


def option_problem(kind: str, low: float, high: float, value) -> "str | None":
    """What is wrong with `value` for an option of this kind and range (``must be …, got
    …``), or None when it is acceptable: the one wording of a range error, shared by the
    command line (``--rtol must be …``) and :func:`phc.simulate` (```rtol` must be …``)."""
    import math

    shown = f"{value:g}" if isinstance(value, float) else str(value)
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond floats
        number = math.nan
    if kind == "count":
        if not (math.isfinite(number) and number == int(number) and low <= number <= high):
            return f"must be a whole number from {low} to {high}, got {shown}"
    elif kind == "fraction":
        if not low < number < high:
            return f"must be a number between {low} and {high} (exclusive), got {shown}"
    elif not (low < number <= high and math.isfinite(number)):
        upper = "" if high == math.inf else f" up to {high:g}"
        return f"must be a finite positive number{upper}, got {shown}"
    return None
