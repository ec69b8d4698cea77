"""Run-time domain errors of the generated functions, caught and explained.

A model expression can leave its domain during a run: ``sqrt``/``log`` of a negative
value, ``asin`` beyond ±1, ``exp`` overflowing, a division by a parameter set to 0. The
generated functions then raise (``ValueError: math domain error``, ``OverflowError``,
``ZeroDivisionError``) or return inf/NaN. :class:`GuardedModule` wraps the generated
module so that every such failure becomes a :class:`ModelEvaluationError` naming

* the function (residual, Jacobian, outputs, Hamiltonian, ...),
* the residual row or output label (from the module's ``EQUATIONS``/``OUTPUTS``) and,
  where known, its place in the model file,
* the expression in model names (generated names translated back) and the values of the
  states and parameters it uses,
* the time,

and the integrators stop cleanly with the results computed so far.

Cost: the fast path adds a ``try`` (free) and one finiteness check of the result (a sum)
per call; only a failed call is re-evaluated (under ``numpy.errstate(raise)``) and its
traceback read to find the failing line of the generated source. Numpy's floating-point
warnings are switched off while a run lasts (:func:`quiet_floating_point`): the checks
report every non-finite value instead.
"""

from __future__ import annotations

import math
import re
from contextlib import contextmanager
from typing import Callable, Optional

import numpy as np

from phc.errors import ModelEvaluationError

# Functions of a generated module: name -> (index of the `out` argument or None when the
# value is returned, what the message calls it)
GUARDED = {
    "residual": (4, "residual"),
    "residual_t": (4, "time derivative of the residual"),
    "jacobian": (5, "Jacobian"),
    "hamiltonian": (None, "Hamiltonian H"),
    "energy_scale": (None, "energy scale"),
    "powers": (None, "port and dissipated power"),
    "invariants": (None, "position invariants"),
    "velocity_invariants": (None, "velocity invariants"),
    "outputs": (None, "outputs"),
}

CATCH = (ArithmeticError, ValueError, TypeError)
"""What an expression of the generated code raises outside its domain: ``ValueError``
(math domain error), ``OverflowError``/``ZeroDivisionError``/``FloatingPointError``
(``ArithmeticError``), ``TypeError`` (a complex power of a negative number)."""

def is_domain_error(err: BaseException) -> bool:
    """Whether `err`, raised inside a generated function, is the model leaving an expression's
    domain — ``ArithmeticError``, ``math domain error``, a complex result — rather than a bug
    in phc (a ``TypeError`` or ``ValueError`` of anything else: wrong shapes, arguments,
    names), which must reach the user as an internal error that says so."""
    if isinstance(err, ArithmeticError):
        return True
    text = str(err)
    if isinstance(err, ValueError) and "math domain error" in text:
        return True
    return isinstance(err, (TypeError, ValueError)) and "complex" in text


REMEDY = "check the expression's domain along the motion and the parameter and initial values"
MAX_EXPR = 160
"""Longest expression quoted in a message (characters)."""


@contextmanager
def quiet_floating_point():
    """No numpy floating-point warnings while a run lasts: the guarded functions report
    non-finite values themselves (underflow stays silent as always)."""
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        yield


def _reason(err: Optional[BaseException]) -> str:
    """A plain-words account of what went wrong."""
    if err is None:
        return "the value is not finite (inf or NaN)"
    text = str(err)
    if isinstance(err, ZeroDivisionError) or "divide by zero" in text:
        return "division by zero (a state or parameter in a denominator is 0)"
    if isinstance(err, OverflowError) or "overflow" in text:
        return "overflow beyond 1.8e308 (exp of an argument above 709, or a power of a huge value)"
    if isinstance(err, ValueError) and "domain" in text:
        return ("a function is evaluated outside its domain (sqrt or log of a negative value, asin/acos "
                "beyond ±1)")
    if "invalid value" in text:
        return "an invalid operation (0/0, inf − inf, a root or log of a negative value)"
    if isinstance(err, TypeError) and "complex" in text:
        return "a complex result (a fractional power of a negative value)"
    return f"{type(err).__name__}: {text}"


class _Source:
    """The generated source, split into functions, for mapping a failing line to its row."""

    ASSIGN = re.compile(r"^\s+(\w+) = _?(y|yp|p)\[(\d+)\]\s*$")  # `x = y[3]`, or `x = _y[3]` after `_y = y.tolist()`
    OUT = re.compile(r"^\s+out\[(\d+)\] = (.*)$")
    LOCAL = re.compile(r"^\s+(\w+) = (.*)$")
    NAME = re.compile(r"\b[A-Za-z_]\w*\b")

    def __init__(self, text: str):
        self.lines = text.splitlines()

    def function_at(self, lineno: int) -> tuple[int, int]:
        """(first, end) line indices (0-based) of the function containing 1-based `lineno`."""
        i = min(max(lineno - 1, 0), len(self.lines) - 1)
        first = i
        while first > 0 and not self.lines[first].startswith("def "):
            first -= 1
        end = i + 1
        while end < len(self.lines) and not self.lines[end].startswith("def "):
            end += 1
        return first, end

    def row(self, lineno: int) -> Optional[int]:
        """Index of the `out[i]` the failing line contributes to (through common subexpressions)."""
        first, end = self.function_at(lineno)
        i = lineno - 1
        m = self.OUT.match(self.lines[i])
        if m:
            return int(m.group(1))
        m = self.LOCAL.match(self.lines[i])
        if not m:
            return None
        used = {m.group(1)}
        for line in self.lines[i + 1:end]:
            names = set(self.NAME.findall(line.split("=", 1)[1])) if "=" in line else set()
            if not names & used:
                continue
            out = self.OUT.match(line)
            if out:
                return int(out.group(1))
            local = self.LOCAL.match(line)
            if local:
                used.add(local.group(1))
        return None

    def expression(self, lineno: int, mod) -> tuple[str, dict, dict]:
        """The failing line's right-hand side in model names (common subexpressions inlined),
        and the variables and parameters it uses as {generated name: (model name, kind, index)}."""
        first, end = self.function_at(lineno)
        inputs, locals_ = {}, {}
        for line in self.lines[first:lineno - 1]:
            m = self.ASSIGN.match(line)
            if m:
                inputs[m.group(1)] = (m.group(2), int(m.group(3)))
                continue
            m = self.LOCAL.match(line)
            if m:
                locals_[m.group(1)] = m.group(2)
        line = self.lines[lineno - 1]
        rhs = line.split("=", 1)[1].strip() if "=" in line else line.strip()

        def inline(text: str, depth: int) -> str:
            if depth > 6:
                return text
            return self.NAME.sub(lambda m: f"({inline(locals_[m.group(0)], depth + 1)})"
                                 if m.group(0) in locals_ and m.group(0).startswith("_c") else m.group(0), text)

        rhs = inline(rhs, 0)
        used_vars, used_pars = {}, {}
        variables, parameters = tuple(getattr(mod, "VARIABLES", ())), tuple(getattr(mod, "PARAMETERS", ()))

        def model_name(m):
            name = m.group(0)
            if name in inputs:
                kind, idx = inputs[name]
                if kind == "p" and idx < len(parameters):
                    used_pars[parameters[idx]] = idx
                    return parameters[idx]
                if kind in ("y", "yp") and idx < len(variables):
                    if kind == "y":
                        used_vars[variables[idx]] = idx
                        return variables[idx]
                    return f"der({variables[idx]})"
            return name

        text = self.NAME.sub(model_name, rhs).replace("math.", "").replace("np.", "")
        if len(text) > MAX_EXPR:
            text = text[:MAX_EXPR - 1] + "…"
        return text, used_vars, used_pars


class GuardedModule:
    """The generated module with its functions checked (see the module docstring).

    Attributes other than the guarded functions are the module's own.

    Parameters
    ----------
    mod : module
        The generated module.
    source : str, optional
        Its source text (to map a failing line to a row); without it, only non-finite
        values are attributed to rows.
    locate : callable, optional
        ``locate(kind, label) -> "file:line" or None`` with kind ``"equation"``,
        ``"output"`` or ``"invariant"``.
    """

    def __init__(self, mod, source: Optional[str] = None,
                 locate: Optional[Callable[[str, str], Optional[str]]] = None):
        self._mod = mod
        self._source = _Source(source) if source else None
        self._locate = locate or (lambda kind, label: None)
        code = getattr(getattr(mod, "full_parameters", None), "__code__", None)
        self._filename = code.co_filename if code is not None else None
        # a compiled module (phc.codegen.numba_backend) is diagnosed with its reference functions:
        # the same rows, evaluated by the printed Python, which raise where the machine code returns NaN
        self._reference = getattr(mod, "REFERENCE", None)
        for name, (out_arg, _) in GUARDED.items():
            func = getattr(mod, name, None)
            if func is not None:
                setattr(self, name, self._wrap(name, func, out_arg))

    def __getattr__(self, name):
        return getattr(self._mod, name)

    @property
    def module(self):
        """The unguarded module."""
        return self._mod

    # -- wrapping ------------------------------------------------------------------------
    def _wrap(self, name, func, out_arg):
        fail = self._fail
        isfinite = math.isfinite
        recover = self._as_written
        if out_arg is not None:
            def guarded(*args):
                try:
                    func(*args)
                except CATCH as err:
                    if not is_domain_error(err):
                        raise  # a bug in phc, not the model: reported as an internal error
                    if recover(name, func, args) is None:
                        raise fail(name, func, args, err) from None
                    return
                if not isfinite(args[out_arg].sum()) and recover(name, func, args) is None:
                    fail_ = fail(name, func, args, None)
                    if fail_ is not None:
                        raise fail_
        else:
            def guarded(*args):
                try:
                    value = func(*args)
                    # (an array's own sum: np.sum's dispatch costs more than the sum itself)
                    total = float(value.sum() if isinstance(value, np.ndarray) else np.sum(value))
                except CATCH as err:
                    if not is_domain_error(err):
                        raise  # a bug in phc, not the model: reported as an internal error
                    value = recover(name, func, args)
                    if value is None:
                        raise fail(name, func, args, err) from None
                    return value
                if not isfinite(total):
                    again = recover(name, func, args)
                    if again is not None:
                        return again
                    fail_ = fail(name, func, args, None)
                    if fail_ is not None:
                        raise fail_
                return value
        guarded.__name__ = name
        guarded.__wrapped__ = func
        return guarded

    # -- diagnosis (slow path: only when a call failed) ----------------------------------
    def _as_written(self, name, func, args):
        """The failed call again with every switching condition evaluated as written (its mode
        0, phc.codegen.nonsmooth), or None. The event driver freezes a condition's side, so a
        row evaluates its branch a little beyond where the condition holds (at the start, a
        condition on its boundary takes the side the motion goes to): there a branch the
        condition discards may be inf or NaN (``ifelse(abs(x) > 1e-9, sin(x)/x, 1)`` at x = 0).
        Its value as written is the model's value; a failure that remains is reported."""
        slots = getattr(self._mod, "SWITCH_SLOTS", None)
        out_arg = GUARDED[name][0]
        at = 2 if name in ("hamiltonian", "energy_scale", "invariants", "velocity_invariants") else 3
        if slots is None or not len(slots) or len(args) <= at:
            return None
        p = np.array(args[at], dtype=float, copy=True)
        slots = np.asarray(slots, dtype=np.int64)
        if not p[slots].any():
            return None  # already as written
        p[slots] = 0.0
        trial = list(args)
        trial[at] = p
        if out_arg is not None:
            trial[out_arg] = np.array(args[out_arg], dtype=float, copy=True)
        try:
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                value = func(*trial)
                value = trial[out_arg] if out_arg is not None else value
                finite = bool(np.all(np.isfinite(np.asarray(value, dtype=float))))
        except CATCH:
            return None
        if not finite:
            return None
        if out_arg is not None:
            args[out_arg][...] = value
        return value

    def _fail(self, name, func, args, err) -> Optional[ModelEvaluationError]:
        out_arg, what = GUARDED[name]
        lineno = None
        owner = self._mod
        if self._reference is not None and getattr(self._reference, name, None) is not None:
            func, err, owner = getattr(self._reference, name), None, self._reference  # evaluated again below
        if err is None:
            # a non-finite value: evaluate again with floating-point errors raised to find
            # the operation; if nothing is raised, the non-finite row is the answer
            trial = list(args)
            if out_arg is not None:
                trial[out_arg] = np.array(args[out_arg], dtype=float, copy=True)
            # on NumPy scalars: the per-step functions read their arguments as Python floats
            # (`_residual(..., _read)`, phc.codegen.printer), whose `*` overflows to inf
            # without a word, where np.errstate raises
            inner = getattr(owner, "_" + name, None)
            try:
                with np.errstate(over="raise", divide="raise", invalid="raise"):
                    value = inner(*trial, list) if inner is not None else func(*trial)
            except CATCH as again:
                err = again
            else:
                value = trial[out_arg] if out_arg is not None else value
                values = np.atleast_1d(np.asarray(value, dtype=float))
                bad = np.flatnonzero(~np.isfinite(values))
                if not len(bad):
                    return None  # a sum that overflowed on finite values: no failure
                return self._error(name, what, args, None, int(bad[0]), None)
        lineno = self._failing_line(err)
        row = self._source.row(lineno) if (self._source is not None and lineno) else None
        return self._error(name, what, args, err, row, lineno)

    def _failing_line(self, err) -> Optional[int]:
        """Line of the generated module where `err` was raised (the deepest frame in it)."""
        tb, line = err.__traceback__, None
        while tb is not None:
            if self._filename is not None and tb.tb_frame.f_code.co_filename == self._filename \
                    and tb.tb_frame.f_code.co_name.lstrip("_") in GUARDED:
                line = tb.tb_lineno
            tb = tb.tb_next
        return line

    def _row_label(self, name, row) -> tuple[str, Optional[str]]:
        """(text naming the row, its source location) for `row` of function `name`."""
        mod = self._mod
        if row is None:
            return "", None
        try:
            if name in ("residual", "residual_t"):
                label = mod.EQUATIONS[row]
                return f"row `{label}`", self._locate("equation", label)
            if name == "jacobian":
                label = mod.EQUATIONS[int(mod.JAC_ROWS[row])]
                return f"row `{label}`", self._locate("equation", label)
            if name == "outputs":
                label = mod.OUTPUTS[row]
                return f"`{label}`", self._locate("output", label)
            if name in ("invariants", "velocity_invariants"):
                labels = mod.INVARIANTS if name == "invariants" else mod.VELOCITY_INVARIANTS
                label = labels[row]
                return f"`{label}`", self._locate("invariant", label)
            if name == "powers":
                return ("(port power)" if row == 0 else "(dissipated power)"), None
        except (IndexError, TypeError, AttributeError):
            pass
        return "", None

    def _error(self, name, what, args, err, row, lineno) -> ModelEvaluationError:
        t = float(args[0])
        label_text, where = self._row_label(name, row)
        subject = {"outputs": "output"}.get(name, what)
        head = f"{subject} {label_text}".strip() if label_text else what
        if where:
            head += f" ({where})"
        parts = [f"{head} cannot be evaluated at t = {t:.6g}: {_reason(err)}"]
        variables, parameters, text = {}, {}, ""
        if self._source is not None and lineno:
            try:
                text, used_vars, used_pars = self._source.expression(lineno, self._mod)
            except (IndexError, ValueError):
                text, used_vars, used_pars = "", {}, {}
            y, p = args[1], args[3] if name not in ("hamiltonian", "energy_scale", "invariants",
                                                     "velocity_invariants") else args[2]
            for vname, idx in used_vars.items():
                variables[vname] = float(np.asarray(y, dtype=float)[idx])
            for pname, idx in used_pars.items():
                parameters[pname] = float(np.asarray(p, dtype=float)[idx])
            if text:
                parts.append(f"in `{text}`")
            values = [f"{k} = {v:.10g}" for k, v in list(variables.items())[:4]]
            values += [f"{k} = {v:.10g}" for k, v in list(parameters.items())[:4]]
            if values:
                parts.append("with " + ", ".join(values))
        parts.append(REMEDY)
        label = None
        if label_text.startswith(("row `", "`")):
            label = label_text.split("`")[1]
        return ModelEvaluationError("; ".join(parts), function=name, t=t, label=label, parameters=parameters,
                                    variables=variables, subject=head, reason=_reason(err), expression=text)


def guard(mod, source: Optional[str] = None, locate=None) -> GuardedModule:
    """:class:`GuardedModule` of `mod` (a guarded module is returned as it is)."""
    if isinstance(mod, GuardedModule):
        return mod
    return GuardedModule(mod, source, locate)
