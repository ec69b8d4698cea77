"""Physical units: parsing with pint, dimensions of expressions, units of port domains.

A model may give its parameters units (``k: {value: 40, unit: N/m}``) and its outputs
units (``x: {value: slider.x, unit: m}``). phc then checks, before anything is compiled,
that every expression is dimensionally consistent where the names it uses carry units:
the terms of a sum, both sides of a comparison, the branches of ``ifelse`` and the
arguments of ``min``/``max``/``atan2`` share one dimension, the arguments of ``sin``,
``exp``, ``log``, ... and exponents are dimensionless, and a component field whose
dimension the component knows from its port domain (a spring's ``k`` is effort per
displacement: N/m in ``mechanical.translational``) has that dimension. Results carry the
units that follow: CSV headers (``output.x [m]``), the JSON summary and plot axes.

Units are parsed by `pint <https://pint.readthedocs.io>`_ (a dependency of
port-hamiltonian-compiler), a maintained library with the SI and its prefixes; the common
SI symbols with prefixes, in products, quotients and integer powers, are read by
:mod:`phc.frontend.si_units` to exactly pint's result (tests/test_units_table.py), so that a
model in SI units is checked without importing pint. Unit text is data: it is first
checked against a short whitelist of characters (names, numbers, ``* / ^ **``,
parentheses, ``·``, superscripts) and a length and exponent limit, and only then read by
the table or handed to pint's parser (which never calls ``eval``). Without pint a unit is
checked only for that syntax, dimensions are not checked, and one warning (PHC-W172) says so.

phc does not convert units: values are used as written, in whatever consistent system of
units the model chooses (SI, or MPa and cm³ for a hydraulic model). Two terms of one
dimension but different scales (``mm`` plus ``m``) are therefore an error, and the
component fields' units must form one system of units (:class:`ScaleSystem`: N/mm beside
a mass in kg, or rpm, is refused with the factor). The rules are explained in
docs/units.md.

Numbers in expressions are scale factors in products and take the dimension of the other
terms in sums (``x - 0.1`` is a length when ``x`` is), as in Modelica. A name without a
unit has an unknown dimension: terms using it are not checked (a sum of known terms
still is).

The one system of units per model (:class:`ScaleSystem`, :func:`scale_terms` and the
scale helpers) is in :mod:`phc.frontend.unit_scales`; its names are importable from here too.
"""

from __future__ import annotations

import functools
import math
import re
from typing import Mapping, Optional

import sympy as sp

from phc.errors import DimensionError, UnitError
from phc.frontend.si_units import ONE, from_pint, parse_table
from phc.frontend.unit_scales import (  # noqa: F401 (importable from phc.frontend.units)
    ScaleSystem, domain_scale, scale_factor, scale_terms, time_scale)

__all__ = ["DOMAIN_UNITS", "NUMBER", "DimensionError", "UnitError", "describe", "dimension",
           "domain_units", "have_pint", "parse_unit", "same_dimension", "unit_label"]

MAX_UNIT_LENGTH = 64
MAX_UNIT_EXPONENT = 12
_UNIT_CHARS = re.compile(r"[A-Za-z0-9_ .*/^()\-·⋅²³¹⁰⁴⁵⁶⁷⁸⁹⁻µμΩ°%]*")
_EXPONENTS = re.compile(r"(?:\^|\*\*)\s*\(?\s*(-?\d+(?:\.\d+)?)")
_SUPERSCRIPTS = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹⁻", "0123456789-")

DOMAIN_UNITS: dict[str, tuple[str, str]] = {
    "mechanical.translational": ("N", "m/s"),
    "mechanical.rotational": ("N*m", "rad/s"),
    "electrical": ("V", "A"),
    "hydraulic": ("Pa", "m^3/s"),
    "thermal": ("K", "W"),
}
"""Effort and flow unit of each physical domain (``generic`` has none). The thermal domain
is the pseudo-bond-graph one that engineers use (temperature and heat flow; their product
is not a power), so a thermal capacitance is J/K and a thermal resistance K/W."""


class _Number:
    """The dimension of a plain number: a factor in a product, any dimension in a sum."""

    def __repr__(self) -> str:
        return "NUMBER"


NUMBER = _Number()


@functools.lru_cache(maxsize=1)
def _registry():
    try:
        import pint
    except ImportError:
        return None
    from phc.frontend.pint_cache import cached_registry

    ureg = cached_registry(pint)
    ureg.define("Ohm = ohm")  # as written in many data sheets (pint knows `ohm` and `Ω`)
    return ureg


@functools.lru_cache(maxsize=1)
def have_pint() -> bool:
    """True when pint is installed (units are checked), False otherwise (syntax only). Does
    not import pint: the common SI units are read from :mod:`phc.frontend.si_units`."""
    import importlib.util

    try:
        return importlib.util.find_spec("pint") is not None
    except (ImportError, ValueError):
        return False


def check_syntax(text: str) -> None:
    """Raise :class:`UnitError` unless `text` looks like a unit expression (no pint needed)."""
    if not isinstance(text, str) or not text.strip():
        raise UnitError("empty unit", "write a unit such as `N/m`, or `1` for a dimensionless quantity")
    if len(text) > MAX_UNIT_LENGTH:
        raise UnitError(f"unit is too long ({len(text)} characters, at most {MAX_UNIT_LENGTH})")
    if not _UNIT_CHARS.fullmatch(text):
        bad = next(ch for ch in text if not _UNIT_CHARS.fullmatch(ch))
        raise UnitError(f"unit `{text}` holds `{bad}`, which no unit has",
                        "a unit is made of unit names, numbers, `*`, `/`, `^` (or `**`) and parentheses, "
                        "e.g. `N*m/rad` or `kg*m^2`")
    for match in _EXPONENTS.finditer(text.translate(_SUPERSCRIPTS)):
        if abs(float(match.group(1))) > MAX_UNIT_EXPONENT:
            raise UnitError(f"exponent {match.group(1)} in unit `{text}` is too large (at most {MAX_UNIT_EXPONENT})")


@functools.lru_cache(maxsize=4096)
def parse_unit(text: str):
    """The unit `text` in SI base units: a :class:`phc.frontend.si_units.Quantity` whose
    magnitude is the unit's scale (0.001 for `mm`); None without pint. The common SI units
    (:data:`phc.frontend.si_units.UNITS` with prefixes, products, quotients and integer
    powers) are read from that table, anything else by pint, to the same result.

    Raises
    ------
    UnitError
        The text is malformed (checked with or without pint), names an unknown unit, or is a
        unit with an offset (`degC`).
    """
    check_syntax(text)
    if not have_pint():
        return None
    plain = text.replace("µ", "u").replace("μ", "u")
    table = parse_table(plain)
    if table is not None:
        return table
    ureg = _registry()
    if ureg is None:
        return None
    import pint

    try:
        unit = ureg.parse_units(plain)
    except pint.errors.UndefinedUnitError as err:
        names = getattr(err, "unit_names", None) or ()
        name = names[0] if isinstance(names, (tuple, list)) and names else str(names or text)
        raise UnitError(f"unknown unit `{name}`" + (f" in `{text}`" if name != text else ""),
                        _unit_hint(name)) from None
    except (pint.errors.PintError, AttributeError, TypeError, ValueError, SyntaxError,
            ZeroDivisionError, OverflowError, RecursionError, KeyError, IndexError,
            AssertionError) as err:  # pint's parser asserts on a dangling operator (`N*`)
        raise UnitError(f"cannot read unit `{text}` ({type(err).__name__})",
                        "write e.g. `N*m/rad`, `kg*m^2` or `m/s^2`") from None
    quantity = ureg.Quantity(1, unit)
    if not quantity._is_multiplicative:
        raise UnitError(f"`{text}` is a unit with an offset; phc does not convert units",
                        "give temperatures in `K` (a temperature difference may be `delta_degC`)")
    try:
        return from_pint(quantity.to_base_units(), ureg)
    except Exception as err:  # noqa: BLE001 — any pint failure on odd input is the user's unit
        raise UnitError(f"cannot read unit `{text}` ({type(err).__name__})") from None


_COMMON = ("m", "s", "kg", "N", "J", "W", "Pa", "V", "A", "Ohm", "F", "H", "K", "rad", "Hz", "N*m", "m/s",
           "rad/s", "N/m", "N*s/m", "kg*m^2", "m^3/s")


def _unit_hint(name: str) -> str:
    import difflib

    close = [c for c in _COMMON if c.lower() == name.lower()] or difflib.get_close_matches(name, _COMMON, n=1,
                                                                                          cutoff=0.6)
    if close:
        return f"did you mean `{close[0]}`? (units are SI names and symbols read by pint: N/m, kg*m^2, ...)"
    return ("use an SI unit name or symbol such as `N/m`, `kg*m^2`, `rad/s` or `1` for a dimensionless "
            "quantity (units are read by pint)")


def is_coherent(quantity) -> bool:
    """True for a coherent SI unit: its scale to the base units is 1 (`N/m` yes, `mm` no)."""
    return quantity is None or math.isclose(float(quantity.magnitude), 1.0, rel_tol=1e-12)


@functools.lru_cache(maxsize=None)
def domain_units(domain: str):
    """``(effort, flow)`` of `domain` as base-unit quantities, or None (`generic`, no pint)."""
    if domain not in DOMAIN_UNITS or not have_pint():
        return None
    effort, flow = DOMAIN_UNITS[domain]
    return parse_unit(effort), parse_unit(flow)


def same_dimension(a, b) -> bool:
    """Both quantities have one dimension and one scale."""
    return (a.dimensionality == b.dimensionality
            and math.isclose(float(a.magnitude), float(b.magnitude), rel_tol=1e-9))


_SUPER = str.maketrans("0123456789-.", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻·")


def _dims_text(quantity) -> str:
    items = sorted(quantity.dimensionality.items(), key=lambda kv: (kv[1] < 0, kv[0]))
    if not items:
        return "dimensionless"
    parts = []
    for name, power in items:
        p = f"{power:g}"
        parts.append(name if p == "1" else name + p.translate(_SUPER))
    return "·".join(parts)


_NAMED = ("N", "N/m", "N*s/m", "N*m", "N*m/rad", "N*m*s/rad", "kg", "kg*m^2", "kg*m^2/rad", "m", "m/s",
          "m/s^2", "rad", "rad/s", "rad/s^2", "V", "A", "Ohm", "H", "F", "C", "Wb", "Pa", "m^3/s", "m^3",
          "Pa*s/m^3", "m^3/Pa", "kg/m^4", "K", "W", "J/K", "K/W", "J", "s", "kg/m", "N*m^2", "N*s/m^2",
          "N*m^2*s", "kg*m", "N*m/A", "N/A", "1/s", "1")
"""Units shown by name when a derived unit equals one of them (`N/m` rather than `kg/s²`)."""


@functools.lru_cache(maxsize=None)
def _named() -> tuple:
    return tuple((text, parse_unit(text)) for text in _NAMED)


_LABELS: dict = {}
"""unit_label by (unit, magnitude): one per kind of variable, not one per variable."""


def unit_label(quantity) -> str:
    """Short ASCII unit text of a base-unit quantity for headers and axes: `N/m`,
    `kg*m^2/s^3`, `1`."""
    try:
        key = (quantity.units, float(quantity.magnitude))
        text = _LABELS.get(key)
    except (TypeError, ValueError):
        key = text = None
    if text is None:
        text = _unit_label(quantity)
        if key is not None:
            if len(_LABELS) >= 4096:
                _LABELS.clear()
            _LABELS[key] = text
    return text


def _unit_label(quantity) -> str:
    for text, named in _named():
        if named.units == quantity.units and math.isclose(float(named.magnitude), float(quantity.magnitude),
                                                          rel_tol=1e-9):
            return text
    text = f"{quantity.units:~C}".replace("**", "^")
    if not text:
        text = "1"
    mag = float(quantity.magnitude)
    if not math.isclose(mag, 1.0, rel_tol=1e-12):
        text = f"{mag:g} {text}" if text != "1" else f"{mag:g}"
    return text


_PREFIXES = {-9: "n", -6: "u", -3: "m", -2: "c", 3: "k", 6: "M", 9: "G"}


def scaled_label(quantity) -> str:
    """:func:`unit_label`, with an SI prefix for a scaled unit where one fits: `mm` rather
    than `0.001 m`, `ms`, `kN/m`, `MPa`, `g`."""
    text = unit_label(quantity)
    mag = float(quantity.magnitude)
    if math.isclose(mag, 1.0, rel_tol=1e-12) or mag <= 0:
        return text
    for name, named in _named():
        if name == "1" or named.units != quantity.units:
            continue
        power = math.log10(mag / float(named.magnitude))
        if name.startswith("kg"):  # the gram takes the prefix: kg·1e-3 = g
            power, name = power + 3, name[1:]
            if abs(power) < 1e-9:
                return name
        prefix = _PREFIXES.get(round(power)) if abs(power - round(power)) < 1e-9 else None
        if prefix is None:
            continue
        candidate = prefix + name
        try:
            if same_dimension(parse_unit(candidate), quantity):
                return candidate
        except UnitError:
            continue
    return text


def describe(quantity, written: Optional[str] = None) -> str:
    """`N/m ([mass]·[time]⁻²)`: the unit (as written when known) and its dimension."""
    shown = written or unit_label(quantity)
    return f"{shown} ({_dims_text(quantity)})"


_DIMENSIONLESS_FUNCTIONS = (sp.sin, sp.cos, sp.tan, sp.asin, sp.acos, sp.atan, sp.sinh, sp.cosh, sp.tanh,
                            sp.exp, sp.log)


class _Walker:
    """Dimension of a sympy expression given base-unit quantities of its symbols."""

    def __init__(self, units: Mapping, written: Mapping):
        self.units, self.written = units, written
        self._one = None
        # pint arithmetic costs tens of µs an operation: products, powers and comparisons of
        # the same quantity objects are done once (a sum of 10⁴ like energy terms repeats a
        # handful); keyed by the operands' ids, which the values keep alive
        self._products: dict = {}
        self._powers: dict = {}
        self._same: dict = {}

    def _mul(self, a, b):
        hit = self._products.get((id(a), id(b)))
        if hit is None:
            hit = self._products[(id(a), id(b))] = (a * b, a, b)
        return hit[0]

    def _pow(self, a, exponent):
        """``a ** float(exponent)`` of a quantity `a` and a sympy number `exponent` (its float
        is sympy's evaluation, a dozen µs: done once per exponent object too)."""
        hit = self._powers.get((id(a), id(exponent)))
        if hit is None:
            hit = self._powers[(id(a), id(exponent))] = (a ** float(exponent), a, exponent)
        return hit[0]

    def _same_dimension(self, a, b) -> bool:
        if a is b:
            return True
        hit = self._same.get((id(a), id(b)))
        if hit is None:
            hit = self._same[(id(a), id(b))] = (same_dimension(a, b), a, b)
        return hit[0]

    def one(self):
        if self._one is None:
            self._one = ONE
        return self._one

    def show(self, term, q) -> str:
        written = self.written.get(term) or self.written.get(-term)  # `-b`: b's unit as written
        return f"`{term}` is {describe(q, written or scaled_label(q))}"

    def common(self, args, what: str):
        """The shared dimension of `args` (a sum's terms, min/max arguments, branches)."""
        known = []
        unknown = False
        for a in args:
            d = self.dim(a)
            if d is None:
                unknown = True
            elif d is not NUMBER:
                known.append((a, d))
        for a, d in known[1:]:
            if not self._same_dimension(known[0][1], d):
                first = known[0]
                if first[1].dimensionality == d.dimensionality:
                    raise DimensionError(f"{what} of one dimension but different scales: "
                                         f"{self.show(*first)} and {self.show(a, d)}; phc does not convert units")
                raise DimensionError(f"{what} of different dimensions: {self.show(*first)} but {self.show(a, d)}")
        if known:
            return known[0][1]
        return None if unknown else NUMBER

    def dimensionless(self, arg, what: str) -> None:
        d = self.dim(arg)
        if d is None or d is NUMBER:
            return
        if d.dimensionality:
            raise DimensionError(f"{what} must be dimensionless, but {self.show(arg, d)}")

    def dim(self, expr):
        if isinstance(expr, sp.Symbol):
            return self.units.get(expr)
        if isinstance(expr, (sp.Number, sp.NumberSymbol)):  # e and π are NumberSymbols
            return NUMBER
        if isinstance(expr, sp.Add):
            return self.common(expr.args, "adds terms")
        if isinstance(expr, sp.Mul):
            dims = [self.dim(a) for a in expr.args]
            if any(d is None for d in dims):
                return None
            known = [d for d in dims if d is not NUMBER]
            if not known:
                return NUMBER
            out = known[0]
            for d in known[1:]:
                out = self._mul(out, d)
            return out
        if isinstance(expr, sp.Pow):
            base, exp = expr.args
            if not exp.is_Number:  # a number is dimensionless: no message to format (x**2 in every H)
                self.dimensionless(exp, f"the exponent `{exp}`")
            db = self.dim(base)
            if db is None:
                return None
            if db is NUMBER:
                return NUMBER if self.dim(exp) is NUMBER else self.one()
            if exp.is_Number:
                return self._pow(db, exp)
            return None
        if isinstance(expr, sp.Piecewise):
            for _, cond in expr.args:
                self.dim(cond)
            return self.common([branch for branch, _ in expr.args], "`ifelse` has branches")
        if isinstance(expr, sp.core.relational.Relational):
            self.common(expr.args, "compares sides")
            return None
        if isinstance(expr, (sp.And, sp.Or, sp.Not)):
            for a in expr.args:
                self.dim(a)
            return None
        if isinstance(expr, (sp.Min, sp.Max)):
            return self.common(expr.args, f"`{type(expr).__name__.lower()}` has arguments")
        if isinstance(expr, sp.atan2):
            self.common(expr.args, "`atan2` has arguments")
            return self.one()
        if isinstance(expr, sp.Abs):
            return self.dim(expr.args[0])
        if isinstance(expr, (sp.sign, sp.Heaviside)):
            self.dim(expr.args[0])
            return self.one()
        if isinstance(expr, _DIMENSIONLESS_FUNCTIONS):
            self.dimensionless(expr.args[0], f"the argument of `{type(expr).__name__}`")
            return self.one()
        for a in getattr(expr, "args", ()):  # anything else: its parts are still checked
            if isinstance(a, sp.Basic):
                self.dim(a)
        return None


def dimension(expr: sp.Basic, units: Mapping, written: Optional[Mapping] = None, symbols: Optional[set] = None):
    """The dimension of `expr`: a base-unit Quantity (:mod:`phc.frontend.si_units`), :data:`NUMBER` (a plain number) or
    None (unknown: it uses a name without a unit).

    Parameters
    ----------
    expr : sympy expression
    units : mapping Symbol -> Quantity
        The base-unit quantities of the symbols that have a unit.
    written : mapping Symbol -> str, optional
        The units as the model wrote them (shown in messages).
    symbols : set, optional
        ``expr.free_symbols`` when the caller has it (a walk of a long sum saved).

    Raises
    ------
    DimensionError
        Parts of `expr` have incompatible dimensions (the message names both).
    """
    if not units or not have_pint() or not isinstance(expr, sp.Basic):
        return None
    free = expr.free_symbols if symbols is None else symbols
    if not (free & units.keys()):
        return None if free else NUMBER
    return _Walker(units, written or {}).dim(expr)


def _type_units(comp):
    """The unit information of `comp`'s type: the ``units`` of its registry entry
    (:mod:`phc.library.registry`), None for a type without one (a nested model)."""
    from phc.library.registry import find

    entry = find(getattr(comp, "type", None))
    return None if entry is None else entry.units


def _element_fields(comp, units):
    """(field, numerator, denominator, meaning) of the fields `comp` gives whose dimension
    follows from its port domain."""
    return [(eu.field, eu.numerator, eu.denominator, eu.meaning) for eu in units.element
            if getattr(comp, eu.field, None) is not None]


_EXPECTED: dict = {}
"""expected_fields by (type, port domains, which of its element fields are given): the
same for every spring of a chain."""


def expected_fields(comp, domains: Mapping[str, str]) -> list[tuple[str, object, str]]:
    """The fields of component `comp` whose dimension its type and port domains fix:
    ``(field, quantity in SI base units, what it is)``. `domains` maps the component's
    local port names to their domains. Empty without pint or where nothing is known
    (the type's ``units`` in :mod:`phc.library.registry`)."""
    units = _type_units(comp)
    if not have_pint() or units is None:
        return []
    key = (getattr(comp, "type", None), id(units), frozenset(domains.items()),
           tuple(getattr(comp, eu.field, None) is not None for eu in units.element or ()))
    found = _EXPECTED.get(key)
    if found is None:
        if len(_EXPECTED) >= 1024:
            _EXPECTED.clear()
        found = _EXPECTED[key] = (units, _expected_fields(comp, domains, units))
    return list(found[1])


def _expected_fields(comp, domains: Mapping[str, str], units) -> list[tuple[str, object, str]]:
    out = []
    if units.si:
        for name, (unit, meaning) in units.si.items():
            out.append((name, parse_unit(unit), f"{meaning}, {unit}"))
        return out
    second = parse_unit("s")
    if units.element:
        doms = set(domains.values())
        if len(doms) != 1:
            return out
        domain_u = domain_units(next(iter(doms)))
        if domain_u is None:
            return out
        e, f = domain_u
        vals = {"e": e, "f": f, "s": second, "1": parse_unit("1")}

        def product(text):
            q = vals["1"]
            for part in text.split("*"):
                q = q * vals[part]
            return q

        for field, num, den, meaning in _element_fields(comp, units):
            quantity = product(num) / product(den)
            out.append((field, quantity, f"{meaning}: {unit_label(quantity)} in {next(iter(doms))}"))
        return out
    if units.ratio is not None and {"a", "b"} <= domains.keys():
        ua, ub = domain_units(domains["a"]), domain_units(domains["b"])
        if ua is None or ub is None:
            return out
        top, bottom = units.ratio
        quantity = ub[top == "f"] / ua[bottom == "f"]
        what = f"{_QUANTITY[top]} of port b / {_QUANTITY[bottom]} of port a"
        out.append(("ratio", quantity, f"{what}: {unit_label(quantity)}"))
    return out


_QUANTITY = {"e": "effort", "f": "flow"}


def variable_units(elab, si: Optional[bool] = None, scales: Optional[Mapping] = None) -> dict:
    """Symbol -> unit of the port variables (by their domain) and of the lumped storage
    states of an elaboration whose declared units are all coherent SI units
    (``elab.units_si``, or `si` when given); empty otherwise: a model in scaled units (MPa,
    cm³) keeps its variables without units, since its port variables are not in the
    domain's SI units. With `scales` (``Elaboration.scales``), the units are those of the
    model's own system of units (mm and ms for a mass–spring in g, N/mm and mm)."""
    if not (getattr(elab, "units_si", False) if si is None else si) or not have_pint():
        return {}
    out = {}
    domain_of = {}
    by_domain: dict = {}  # one quantity object per domain and role: shared, and pint is slow

    def scaled(domain):
        if domain in by_domain:
            return by_domain[domain]
        units = domain_units(domain)
        if units is not None and scales:
            units = (units[0] * 10.0 ** domain_scale(scales, domain, "E"),
                     units[1] * 10.0 ** domain_scale(scales, domain, "F"))
        by_domain[domain] = units
        return units

    for port in elab.ports.values():
        units = scaled(port.domain)
        if units is None:
            continue
        domain_of.setdefault(port.component, set()).add(port.domain)
        for sym in port.e:
            out[sym] = units[0]
        for sym in port.f:
            out[sym] = units[1]
    second = parse_unit("s") * 10.0 ** time_scale(scales)
    specs = elab.component_specs
    of_type: dict = {}  # the registry's units by component type: looked up once per type
    for v in elab.variables:
        if v.role != "state" or v.component not in specs:
            continue
        spec = specs[v.component]
        kind = getattr(spec, "type", None)
        units = of_type.get(kind, of_type)
        if units is of_type:
            units = of_type[kind] = _type_units(spec)
        domains = domain_of.get(v.component, set())
        if units is None or units.storage is None or len(domains) != 1:
            continue
        domain = next(iter(domains))
        which = units.storage_of(v.name[len(v.component) + 1:]) == "e"
        if (domain, which) not in by_domain:
            e, f = scaled(domain)
            by_domain[(domain, which)] = (e if which else f) * second
        out[v.symbol] = by_domain[(domain, which)]
    return out


class ResultUnits:
    """Units of an assembled model's results: each output's unit, declared (`{value, unit}`)
    or derived from the dimension of its expression, and the units of its variables and of
    `H`. Checks outputs and initial values through `reporter` (its `units` are set here)."""

    def __init__(self, reporter, elab, variables, hamiltonian, h_symbols: Optional[set] = None):
        self.reporter = reporter
        self.active = bool(elab.units) and have_pint()
        self.labels: dict[str, str] = {}
        if not self.active:
            return
        units = dict(elab.units)
        units.update(variable_units(elab))
        self.h_symbol = sp.Symbol("H", real=True)
        self.rotational = any(getattr(p, "domain", None) == "mechanical.rotational" for p in elab.ports.values())
        try:
            h = dimension(hamiltonian, units, symbols=h_symbols)
        except DimensionError:
            h = None
        if h is not None and h is not NUMBER:
            units[self.h_symbol] = h
            joule = parse_unit("J")
            # radians are dimensionless: k·x²/2 of a torsion spring is N·m/rad · rad² = J
            self.labels["H"] = "J" if same_dimension(h, joule) else unit_label(h)
            self.labels["energy.supplied"] = self.labels["H"]
        reporter.units = units
        reporter.unit_text = dict(elab.unit_text)
        # the states' units where the components are in SI (a spring's `k` in N/m) even when
        # some parameter elsewhere is not (an initial value in mm): initial values are checked
        # against them, scale included, since phc does not convert units; in the model's own
        # system of units (ScaleSystem) where its fields are scaled (mm for g, N/mm and ms)
        scales = getattr(elab, "scales", None)
        if time_scale(scales):  # the time column is in the model's time unit (ms in mm, g, ms)
            self.labels["t"] = scaled_label(parse_unit("s") * 10.0 ** time_scale(scales))
        self.state_units = (variable_units(elab, si=True, scales=scales) if (scales or getattr(
            elab, "fields_si", False)) and not elab.units_si else {})
        labels: dict = {}
        for v in variables:
            q = units.get(v.symbol)
            if q is not None:
                if id(q) not in labels:
                    labels[id(q)] = (unit_label(q), q)
                self.labels[v.name] = labels[id(q)][0]
        scope: dict = {"H": self.h_symbol}
        vectors: dict = {}
        for v in elab.variables:
            if v.name.endswith("]"):
                base, idx = v.name[:-1].rsplit("[", 1)
                vectors.setdefault(base, {})[int(idx)] = v.symbol
            else:
                scope[v.name] = v.symbol
        for base, items in vectors.items():
            scope[base] = [items[i] for i in sorted(items)]
        for p in elab.parameters.values():
            scope[p.name] = p.symbol
        for name in elab.extra_outputs:
            base = name[:-1].rsplit("[", 1)[0] if name.endswith("]") else name
            if base not in scope:
                n = sum(1 for other in elab.extra_outputs if other.startswith(base + "["))
                scope[base] = [sp.Dummy() for _ in range(n)] if n else sp.Dummy()
        from phc.ir.dae import T

        scope["t"] = T
        self.scope = scope
        # der(x) in outputs: a state's unit per unit of time (the model's time unit)
        from phc.spec.expressions import named_scope

        second = parse_unit("s") * 10.0 ** (time_scale(scales) or 0)
        self.rates = {}
        per_second: dict = {}  # the states share a few quantity objects (variable_units)
        for v in elab.variables:
            if v.differential and v.dsymbol is not None:
                self.rates[v.name] = v.dsymbol
                if v.symbol in units:
                    q = units[v.symbol]
                    if id(q) not in per_second:
                        per_second[id(q)] = (q / second, q)
                    units[v.dsymbol] = per_second[id(q)][0]
        self.rates = named_scope(self.rates.items())

    def output(self, ctx, name: str, value, path, unit: Optional[str], unit_path) -> Optional[float]:
        """Check output `name` (its `value` at `path`, its declared `unit` at `unit_path`)
        and record its unit. Returns the factor that converts the value from the model's
        units into the declared unit (1000 for a length in m declared in mm), or None when
        there is none to apply."""
        factor = None
        declared = None
        if unit is not None:
            try:
                declared = parse_unit(unit)
            except UnitError as err:
                self.reporter.error("PHC-E170", f"output `{name}`: {err.message}", ctx, unit_path, hint=err.hint)
                return
        if not self.active:
            if unit is not None and declared is not None:
                self.labels[name] = unit
            elif unit is not None:
                self.labels[name] = unit  # without pint: the unit as written (spelling checked)
            return
        from phc.spec.expressions import ExpressionError, parse_expression

        try:
            expr = parse_expression(value, self.scope, rates=self.rates)
        except ExpressionError:
            dim = scaled = None  # reported where the output was parsed
        else:
            n_errors = len(self.reporter.diags.errors)
            dim = scaled = self.reporter.dimension(ctx, value, path, expr)
            if self.state_units and len(self.reporter.diags.errors) == n_errors:
                scaled = self._in_model_units(ctx, value, path, expr)
        if declared is not None:
            if dim is not None and dim is not NUMBER and dim.dimensionality != declared.dimensionality:
                self.reporter.error("PHC-E172", f"output `{name}` is declared in {describe(declared, unit)} but "
                                    f"its value `{value}` is in {describe(dim)}", ctx, path,
                                    hint="correct the expression or the output's `unit:`")
            elif (scaled is not None and scaled is not NUMBER and scaled.dimensionality == declared.dimensionality
                  and not same_dimension(scaled, declared)):
                # the value is in the model's units (m) and declared in another scale (mm): the
                # output is converted, so that its numbers are what its label says (docs/units.md)
                factor = scale_factor(scaled, declared)
            self.labels[name] = unit
        elif dim is not None and dim is not NUMBER:
            self.labels[name] = self._label(dim, expr)
        return factor

    def _label(self, dim, expr) -> str:
        """The label of an output of dimension `dim` (its value `expr`): an energy is `J` where
        it is one — an expression of `H`, or any energy of a model without rotational ports —
        and `N*m` (a torque) otherwise; the two share one dimension, radians being
        dimensionless (docs/units.md)."""
        if same_dimension(dim, parse_unit("J")) and (self.h_symbol in expr.free_symbols or not self.rotational):
            return "J"
        return unit_label(dim)

    def _in_model_units(self, ctx, value, path, expr):
        """The dimension of an output's expression with the states and port variables in the
        model's system of units (:attr:`state_units`), where its parameters' units alone leave
        them without one: `spring.x - b` with `b` in mm for a spring in m is refused (PHC-E171)."""
        units = dict(self.state_units)
        units.update(self.reporter.units)
        try:
            return dimension(expr, units, self.reporter.unit_text)
        except DimensionError as err:
            self.reporter.error("PHC-E171", f"in expression `{value}`: {err}", ctx, path,
                                hint="every term of a sum (and both sides of a comparison) needs the same unit; "
                                "the states and port variables are in the model's system of units (docs/units.md: "
                                "one system of units per model), so give the parameter in theirs")
            return None

    def initial(self, ctx, name: str, path) -> None:
        """Check an initial value (parsed at `path`) against its state's unit."""
        if not self.active:
            return
        symbol = sp.Symbol(name, real=True)
        want = self.reporter.units.get(symbol) or self.state_units.get(symbol)
        dim = self.reporter.expr_dims.get((id(ctx.smap), tuple(path)))
        if want is None or dim is None or dim is NUMBER or same_dimension(want, dim):
            return
        written = _written_unit(ctx, path, self.reporter.unit_text)
        if want.dimensionality == dim.dimensionality:  # mm for a state in m: a factor 1000, silently
            factor = float(dim.magnitude) / float(want.magnitude)
            need = scaled_label(want)
            self.reporter.error(
                "PHC-E172", f"initial value of `{name}` is in {describe(dim, written)}, but `{name}` is in "
                f"{describe(want, need)}: the same dimension in another scale, and phc does not convert units "
                f"(1 {written or scaled_label(dim)} = {factor:g} {need})", ctx, path,
                hint=f"give the initial value in {need}: multiply the number by {factor:g}, or "
                "declare the parameter it uses in that unit")
            return
        self.reporter.error("PHC-E172", f"initial value of `{name}` is in {describe(dim, written)}, but `{name}` "
                            f"is in {describe(want)}", ctx, path, hint="check the units of the parameters it uses")


def _written_unit(ctx, path, unit_text: Mapping) -> Optional[str]:
    """The unit as written of an initial value that is one parameter (`x0` in `mm`), else None."""
    try:
        spec = ctx.spec.simulation.initial
        value = spec.get(path[2]) if len(path) > 2 else None
    except AttributeError:
        return None
    value = getattr(value, "value", value)
    if not isinstance(value, str):
        return None
    for symbol, text in unit_text.items():
        if symbol.name == (ctx.prefix or "") + value.strip():
            return text
    return None
