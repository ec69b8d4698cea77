"""What each generated function computes, for the compiled back ends.

Input: a :class:`~phc.codegen.lower.ResidualIR`. Output: one :class:`FunctionKernel` per
function the compiled back ends replace (:func:`function_kernels`): the scalar expressions it
writes into its output vector and the sparse sums (linear blocks, quadratic forms) it adds.
The numba back end (:mod:`phc.codegen.numba_backend`, :mod:`phc.codegen.numba_emit`) and the
C back end (:mod:`phc.codegen.c_printer`) print the same kernels, each in its own language;
the NumPy module (:mod:`phc.codegen.printer`, the reference) computes the same values with
NumPy idioms (one fused sparse matrix per derivative, scipy's products).
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Sequence
from typing import Optional

import numpy as np
import scipy.sparse as sps
import sympy as sp

from phc.frontend.budget import drop_deltas
from phc.codegen.lower import ResidualIR
from phc.codegen.printer import _cse, energy_scale_expression, shared_cse
from phc.codegen.repeat import REPEAT_MIN, Repeated, repeated, slot  # noqa: F401 (the back ends' names)
from phc.ir.dae import STORED_ENERGY, T

CJ = sp.Symbol("cj")
"""The Jacobian's factor of dF/dẏ (an argument of ``jacobian``)."""


@dataclass(frozen=True)
class Kernel:
    """What a function computes into its output vector ``out``: `targets` are ``(index,
    expression, accumulate)`` written (or added) into ``out``, then `sums` are added:
    ``("matvec", A, rows, cols, "y"|"yp", coeff)`` adds ``coeff·A v[cols]`` to ``out[rows]``;
    ``("scatter", pos, data, coeff, times_cj)`` adds ``coeff·data`` (times cj) to ``out[pos]``;
    ``("quad", A, cols, coeff, index, absolute)`` adds ``coeff·xᵀAx`` (its absolute value) to
    ``out[index]``; ``("grad", A, cols, pos, coeff)`` adds ``coeff·A x`` to ``out[pos]``
    (x = y[cols], A a CSR matrix). With `energy` (the kernel of ``hamiltonian``), the stored
    energy H is computed first, once, and is the value of :data:`~phc.ir.dae.STORED_ENERGY` in
    the targets (an output that uses `H`)."""

    targets: tuple
    sums: tuple = ()
    energy: Optional["Kernel"] = None

    def expressions(self) -> list:
        """The target expressions, then the coefficient of each sum."""
        return [e for _, e, _ in self.targets] + [_coefficient(op) for op in self.sums]


_COEFFICIENT = {"matvec": 5, "scatter": 3, "quad": 3, "grad": 4}


def _coefficient(op):
    """The coefficient expression of a :class:`Kernel` sum."""
    return op[_COEFFICIENT[op[0]]]


def kernel_cse(ir: ResidualIR, kernel: Kernel, targets: Optional[tuple] = None) -> tuple[list, list]:
    """Common subexpressions of `kernel`'s expressions (its `targets`, else all of them), as
    the compiled back ends print them: ``(replacements, reduced)``, the reduced target
    expressions then the reduced coefficient of each sum. Searched once per IR, shared with
    the NumPy module's printer (:func:`phc.codegen.printer.shared_cse`): the whole list where
    that printer searched it (the energy and its quadratic forms' coefficients), else the
    targets' list (the rows of the residual and the Jacobian), then the coefficients
    (parameters only) among themselves, with symbols of their own (:class:`sympy.Dummy`)."""
    targets = kernel.targets if targets is None else targets
    exprs = [e for _, e, _ in targets]
    coefficients = [_coefficient(op) for op in kernel.sums]
    whole = ir.common_subexpressions.get(tuple(exprs + coefficients))
    if whole is not None:
        return whole
    replacements, reduced = shared_cse(ir, exprs)
    if coefficients:
        more, rest = _cse(coefficients, sp.numbered_symbols("_c", cls=sp.Dummy))
        replacements, reduced = [*replacements, *more], [*reduced, *rest]
    return replacements, reduced


def _canonical(matrix):
    """`matrix` as a CSR matrix with sorted indices and no duplicates (its entry order is
    the one :class:`~phc.codegen.lower.LinearTermIR` positions refer to)."""
    m = sps.csr_matrix(matrix)
    m.sum_duplicates()
    m.sort_indices()
    return m


@dataclass(frozen=True)
class FunctionKernel:
    """One generated function: its name, what it computes, and its output vector."""

    name: str
    kernel: Kernel
    size: int
    """Entries of the output vector."""
    zero: bool
    """Whether the output is zeroed before the targets are written (some are accumulated,
    or not every entry is a target)."""
    args: str
    """``"yyp"`` (t, y, yp, p), ``"yyp_cj"`` (t, y, yp, p, cj) or ``"y"`` (t, y, p)."""
    returns: str
    """``"out"`` (written into the caller's ``out``), ``"array"`` (a new vector),
    ``"scalar"`` (its one entry) or ``"pair"`` (its two entries)."""
    labels: tuple = ()
    """A name for each entry (the equation, Jacobian entry, output...), for comments."""


class JacobianLabels(Sequence):
    """``d(row)/d(variable)`` of each Jacobian entry, made when read (a comment names the few
    entries a function writes; a mesh of 10⁵ elements has 5.4·10⁶ entries)."""

    def __init__(self, ir: ResidualIR) -> None:
        self._ir = ir

    def __len__(self) -> int:
        return len(self._ir.jac_rows)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return tuple(self[i] for i in range(*k.indices(len(self))))
        ir = self._ir
        return f"d({ir.equation_labels[int(ir.jac_rows[k])]})/d({ir.variables[int(ir.jac_cols[k])]})"


def function_kernels(ir: ResidualIR) -> list[FunctionKernel]:
    """The kernels of ``residual``, ``residual_t``, ``jacobian``, ``hamiltonian``,
    ``energy_scale``, ``powers``, ``invariants``, ``velocity_invariants`` and ``outputs``."""
    lin, qd, qe = ir.linear_terms, ir.quadratic_dissipation, ir.quadratic_energy
    sums = bool(lin or qd)
    m, njac = len(ir.residual), len(ir.jac_rows)
    out = []
    res_sums = tuple(("matvec", t.matrix, t.rows, t.cols, "yp" if t.derivative else "y", t.coeff) for t in lin)
    res_sums += tuple(("quad", f.matrix, f.cols, -f.coeff, ir.energy_row, False) for f in qd)
    rows = [(i, e) for i, e in enumerate(ir.residual) if e != 0] if sums else list(enumerate(ir.residual))
    out.append(FunctionKernel("residual", Kernel(tuple((i, e, False) for i, e in rows), res_sums), m, sums,
                              "yyp", "out", ir.equation_labels))
    dt_rows = [(i, drop_deltas(sp.diff(e, T))) for i, e in enumerate(ir.residual)
               if e != 0 and e.has(T)]  # most rows of a mesh are 0 (linear blocks): no diff
    out.append(FunctionKernel("residual_t", Kernel(tuple((i, e, False) for i, e in dt_rows if e != 0)), m, True,
                              "yyp", "out", ir.equation_labels))
    # dF/dy + cj·dF/dẏ where it has a symbolic part; every other entry is 0 but for the blocks
    jac_symbolic = [(k, dy + CJ * dyp if dyp != 0 else dy) for k, dy, dyp in ir.jac_symbolic]
    if sums:
        jac_sums = tuple(("scatter", t.pos, _canonical(t.matrix).data, t.coeff, t.derivative) for t in lin)
        jac_sums += tuple(("grad", f.matrix, f.cols, f.pos, -2 * f.coeff) for f in qd)
        kernel = Kernel(tuple((k, e, True) for k, e in jac_symbolic if e != 0), jac_sums)
    else:
        jac = [sp.S.Zero] * njac
        for k, e in jac_symbolic:
            jac[k] = e
        kernel = Kernel(tuple((k, e, False) for k, e in enumerate(jac)))
    out.append(FunctionKernel("jacobian", kernel, njac, sums, "yyp_cj", "out", JacobianLabels(ir)))
    energy = Kernel(((0, ir.hamiltonian, False),), tuple(("quad", f.matrix, f.cols, f.coeff, 0, False) for f in qe))
    out.append(FunctionKernel("hamiltonian", energy, 1, False, "y", "scalar", ("H",)))
    scale = energy_scale_expression(ir)
    out.append(FunctionKernel(
        "energy_scale",
        Kernel(((0, scale, False),), tuple(("quad", f.matrix, f.cols, f.coeff, 0, True) for f in qe)),
        1, False, "y", "scalar", ("sum of |terms| of H",)))
    out.append(FunctionKernel(
        "powers", Kernel(((0, ir.port_power, False), (1, ir.dissipation, False)),
                         tuple(("quad", f.matrix, f.cols, f.coeff, 1, False) for f in qd)),
        2, False, "yyp", "pair", ("P_ports", "P_diss")))
    for name, exprs, labels in (("invariants", ir.invariants, ir.invariant_labels),
                                ("velocity_invariants", ir.velocity_invariants, ir.velocity_invariant_labels)):
        out.append(FunctionKernel(name, Kernel(tuple((i, e, False) for i, e in enumerate(exprs))), len(exprs), False,
                                  "y", "array", tuple(labels)))
    # an output that uses H refers to the value of `hamiltonian`, computed first (sparse forms)
    uses_energy = any(e.has(STORED_ENERGY) for _, e in ir.outputs)
    out.append(FunctionKernel("outputs", Kernel(tuple((i, e, False) for i, (_, e) in enumerate(ir.outputs)),
                                                energy=energy if uses_energy else None),
                              len(ir.outputs), False, "yyp", "array", tuple(name for name, _ in ir.outputs)))
    return out


def events_kernel(ir: ResidualIR) -> FunctionKernel:
    """The kernel of ``events(t, y, yp, p, out)``, the switching functions (:attr:`ResidualIR.events`):
    not one of :func:`function_kernels` (the numba back end leaves ``events`` as the NumPy module's
    text); the C back end prints it as ``phc_events``, which the C step loop watches."""
    labels = tuple(s.label for s in ir.switches) + tuple(s.label for s in ir.sticks)
    return FunctionKernel("events", Kernel(tuple((i, e, False) for i, e in enumerate(ir.events))), len(labels),
                          False, "yyp", "out", labels)


__all__ = ["CJ", "FunctionKernel", "Kernel", "REPEAT_MIN", "Repeated", "events_kernel", "function_kernels",
           "kernel_cse", "repeated", "slot"]


def product_parts(e: sp.Mul, order: str) -> tuple[bool, list, list]:
    """``(negative, numerator, denominator)`` of a product, split as sympy's code printer
    splits it (the NumPy module's order of operations): a negative coefficient taken out,
    factors with a negative rational exponent in the denominator. `order` is the printer's
    ``order`` setting. The compiled back ends evaluate a product in this order so that their
    values match the reference module's to the last bit where the operations are the same."""
    from sympy.core.mul import _keep_coeff

    c, rest = e.as_coeff_Mul()
    negative = bool(c < 0)
    if negative:
        e = _keep_coeff(-c, rest)
    args = e.as_ordered_factors() if order not in ("old", "none") else sp.Mul.make_args(e)
    num, den = [], []
    for item in args:
        if item.is_commutative and item.is_Pow and item.exp.is_Rational and item.exp.is_negative:
            den.append(sp.Pow(item.base, -item.exp, evaluate=False) if item.exp != -1 else sp.Pow(item.base, -item.exp))
        else:
            num.append(item)
    return negative, num or [sp.S.One], den
