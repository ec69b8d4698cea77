"""The C text of an FMU's FMI 2.0 co-simulation interface (``fmu.c``).

Input: an :class:`FmuData` — everything about the model the interface needs (sizes, the
start state, the parameters, the step loop's constants, the variables by value reference),
computed by :mod:`phc.export.fmu`. Output: the text of ``fmu.c`` (:func:`fmu_source`), one
translation unit that, compiled together with the model's ``model.c`` (the C back end's
file, :mod:`phc.codegen.c_printer`), is the FMU's binary. It includes ``steps.c``
(``phc/codegen/c_runtime/steps.c``: the implicit midpoint rule's step loop that
``phc simulate --backend c`` runs), defines the model's constants, and includes
``fmi2_cs.c`` (``phc/codegen/c_runtime/fmi2_cs.c``: the FMI functions, hand-written once for
every FMU, over those constants); both files ship beside it in the FMU's ``sources/``. An
``fmi2DoStep`` is one call of ``phc_steps_chunk`` over the communication interval, so the FMU
takes exactly the steps ``phc simulate`` takes on the same grid.

The FMI 2.0 types are declared in ``fmi2_cs.c``, as the standard's headers
(``fmi2TypesPlatform.h``, ``fmi2FunctionTypes.h``, "default" platform) define them. Each
instance owns its memory (allocated through the importer's ``allocateMemory``); no file has
mutable static data, so instances may run in parallel threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from phc import __version__
from phc.codegen.c_printer import ABI, comment, number

FMI2_CS = Path(__file__).resolve().parents[1] / "codegen" / "c_runtime" / "fmi2_cs.c"
"""The FMI 2.0 co-simulation functions (C, shipped with phc), included by every ``fmu.c``."""

KINDS = ("VARIABLE", "PARAMETER", "CONSTANT", "INPUT", "OUTPUT", "ENERGY", "BALANCE")
"""What a value reference reads (the C file's ``K_*``): a model variable y[i], a base
parameter p[i] (set before the run), a parameter fixed at compile time, an input (a parameter
the importer sets between steps), a model output, the stored energy H, the energy-balance
error H(t) - H(t0) + E(t)."""


@dataclass(frozen=True)
class FmuVariable:
    """One FMI scalar variable (value reference = its position in :attr:`FmuData.variables`)."""

    name: str
    kind: str
    """One of :data:`KINDS`."""
    index: int
    """Index into y, p or the outputs (0 for ENERGY and BALANCE)."""
    causality: str
    variability: str
    initial: Optional[str]
    start: Optional[float]
    unit: Optional[str]
    description: str
    fixes_start: bool = False
    """A parameter whose value the consistent initial state depends on."""


@dataclass(frozen=True)
class FmuData:
    """What ``fmu.c`` embeds (see the module docstring)."""

    model: str
    guid: str
    n: int
    njac: int
    nend: int
    nout: int
    ninv: int
    nrows: int
    npred: int
    t0: float
    step: float
    """Longest step (0: one step per communication interval)."""
    energy_index: int
    p: np.ndarray
    """Full parameter vector at the exported values."""
    derived: tuple[str, ...]
    """C statements computing the derived parameters from p, in dependency order."""
    y0: np.ndarray
    yp0: np.ndarray
    weights: Optional[np.ndarray]
    colscale: Optional[np.ndarray]
    constants: np.ndarray
    jrows: np.ndarray
    jcols: np.ndarray
    end_rows: np.ndarray
    emask: np.ndarray
    algmask: np.ndarray
    variables: tuple[FmuVariable, ...]


def _c_string(text: str) -> str:
    """A C string literal of printable ASCII (anything else as a question mark)."""
    out = []
    for ch in str(text):
        if ch in "\\\"":
            out.append("\\" + ch)
        elif " " <= ch <= "~" and ch != "%":  # no % (a logger may format the message)
            out.append(ch)
        else:
            out.append("?")
    return '"' + "".join(out) + '"'


def _doubles(name: str, values, comment_text: str = "") -> str:
    values = np.asarray(values, dtype=float).ravel()
    items = [number(float(v)) for v in values] or ["0.0"]
    body = ",\n".join("    " + ", ".join(items[i:i + 6]) for i in range(0, len(items), 6))
    note = f"/* {comment(comment_text)} */\n" if comment_text else ""
    return f"{note}static const double {name}[{len(items)}] = {{\n{body}\n}};\n"


def _ints(name: str, values, ctype: str, comment_text: str = "") -> str:
    values = [int(v) for v in np.asarray(values).ravel()] or [0]
    body = ",\n".join("    " + ", ".join(str(v) for v in values[i:i + 16]) for i in range(0, len(values), 16))
    note = f"/* {comment(comment_text)} */\n" if comment_text else ""
    return f"{note}static const {ctype} {name}[{len(values)}] = {{\n{body}\n}};\n"


def _variable_table(variables: Sequence[FmuVariable]) -> str:
    rows = [f"    {{K_{v.kind}, {v.index}, {int(v.fixes_start)}, {_c_string(v.name)}}},  /* vr {k} */"
            for k, v in enumerate(variables)]
    return ("/* the variables by value reference: what each reads, its index, whether the start state depends on it\n"
            " * (a parameter), its name (modelDescription.xml lists the same, in the same order) */\n"
            "static const struct fmu_variable VARIABLES[NVR] = {\n" + "\n".join(rows) + "\n};\n")


def fmu_source(d: FmuData) -> str:
    """The text of ``fmu.c`` for `d` (see the module docstring)."""
    kinds = ", ".join(f"K_{k}" for k in KINDS)
    derived = "\n".join(f"    {line}" for line in d.derived) or "    (void)p;  /* none */"
    data = "\n".join([
        f"#define N {d.n}              /* unknowns y */",
        f"#define NJAC {d.njac}         /* Jacobian entries */",
        f"#define NEND {d.nend}         /* position-constraint rows imposed at the step end */",
        f"#define NP {len(d.p)}           /* parameters p (base, derived) */",
        f"#define NOUT {d.nout}         /* model outputs */",
        f"#define NPRED {d.npred}        /* midpoints the predictor keeps */",
        f"#define NVR {len(d.variables)}          /* value references */",
        f"#define ENERGY_INDEX {d.energy_index}  /* y[ENERGY_INDEX]: energy.supplied, E(t) */",
        f"#define HAS_WEIGHTS {int(d.weights is not None)}",
        f"#define HAS_COLSCALE {int(d.colscale is not None)}",
        "",
        f"static const char GUID[] = {_c_string(d.guid)};",
        f"static const char MODEL[] = {_c_string(d.model)};",
        f"static const double T0 = {number(d.t0)};  /* the start time the initial state is consistent at */",
        f"static const double STEP = {number(d.step)};  /* longest step; 0: one step per communication interval */",
        f"static const long long SIZES[8] = {{{ABI}, {d.n}, {d.nrows}, {d.njac}, {len(d.p)}, {d.ninv}, -1, {d.nout}}};",
        "",
        _doubles("P_EXPORTED", d.p, "the parameters p at the values exported (full_parameters of the NumPy module)"),
        _doubles("Y0", d.y0, "the consistent initial state at the exported parameters (phc's initialization)"),
        _doubles("YP0", d.yp0, "its rates"),
        _doubles("WEIGHTS", d.weights if d.weights is not None else [0.0],
                 "Newton weights (1/nominal scale of the differential variables, 0 elsewhere)"),
        _doubles("COLSCALE", d.colscale if d.colscale is not None else [0.0], "nominal scales"),
        _doubles("CONSTANTS", d.constants, "the step logic's constants (phc.simulation.step_logic)"),
        "/* steps.c reads C_NC of them: a compile error if phc and steps.c disagree */\n"
        "typedef char constants_match_steps_c[sizeof CONSTANTS / sizeof CONSTANTS[0] == C_NC ? 1 : -1];\n",
        _ints("JROWS", d.jrows, "int64_t", "the Jacobian's pattern: rows"),
        _ints("JCOLS", d.jcols, "int64_t", "columns"),
        _ints("END_ROWS", d.end_rows, "int64_t", "rows replaced by the position constraints at the step end"),
        _ints("EMASK", d.emask, "int8_t", "1 where a Jacobian entry lies in such a row"),
        _ints("ALGMASK", d.algmask, "int8_t", "0 differential, 1 algebraic, 2 a GGL multiplier"),
        _variable_table(d.variables),
    ])
    head = _HEAD.replace("@MODEL@", comment(d.model)).replace("@VERSION@", comment(__version__))
    rule = "\n/* ---- the model (the constants phc computed when it exported it) " + "-" * 29 + " */\n\n"
    return (head + rule + f"enum {{ {kinds} }};\n\n" + _STRUCT_VARIABLE + "\n" + data + "\n"
            + "/* the derived parameters from the base ones, in dependency order (full_parameters) */\n"
            + "static void derived_parameters(double *p)\n{\n" + derived + "\n}\n\n"
            + "#include \"fmi2_cs.c\" /* the FMI 2.0 co-simulation functions over these constants */\n")


_HEAD = r"""/* FMI 2.0 co-simulation interface of the port-Hamiltonian model `@MODEL@`,
 * generated by phc @VERSION@. Do not edit: export again with `phc export MODEL --fmu OUT.fmu`.
 *
 * The model's DAE F(t, y, yp, p) = 0 (model.c, the C back end's functions) is integrated by the
 * implicit midpoint rule with the position constraints imposed at the step ends (the GGL
 * formulation of T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian modelling of
 * coupled rigid/flexible multibody systems", the rigid multibody DAE, eq. (3)): the step loop of
 * steps.c, which `phc simulate --backend c --solver midpoint` runs too. fmi2DoStep(t, H) splits
 * [t, t + H] into ceil(H / STEP) equal steps (one when STEP is 0) and takes them; the energy
 * balance H(t) - H(t0) + E(t) = 0 (E: the energy supplied through the ports and dissipated)
 * then holds per step to the Newton tolerance when H is quadratic, as the midpoint rule keeps
 * the power balance of a port-Hamiltonian system (the paper's Remark 3).
 *
 * What the importer may set: the parameters before fmi2ExitInitializationMode (the start state
 * was computed by phc at the exported values: a parameter it depends on is refused with a logged
 * error, export again with the value), the other parameters between steps too (tunable), the
 * inputs at any time (held constant over a communication interval; each is added to the value the
 * model gives the source or port, 0 for a free port).
 * Not offered: fmi2GetFMUstate and its kin, directional derivatives, input derivatives.
 *
 * This file holds the model's constants; the FMI functions over them are fmi2_cs.c (shipped with
 * phc, included at the end). Re-entrant: no mutable static data; every instance owns its memory.
 */

#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "steps.c" /* the implicit midpoint rule's step loop (phc_steps_chunk) */
"""

_STRUCT_VARIABLE = r"""struct fmu_variable {
    int kind;         /* K_* */
    int index;        /* into y, p or the outputs */
    int fixes_start;  /* a parameter the consistent initial state depends on */
    const char *name;
};
"""


__all__ = ["FMI2_CS", "FmuData", "FmuVariable", "KINDS", "fmu_source"]
