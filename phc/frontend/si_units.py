"""Units in SI base units: the quantities phc's unit checks compute with, and a table of the
common SI units read without building pint's registry.

Building pint's ``UnitRegistry`` and importing pint (which imports dask when dask is
installed) cost about a second of CPU in a fresh process, a third of a cold ``phc compile``.
Most models write only SI symbols with SI prefixes (``N/m``, ``kg*m^2``, ``mm``, ``kN``),
so phc reads those from :data:`UNITS` and :data:`PREFIXES` below, and hands pint only text
outside that small grammar or that table (``rpm``, ``deg``, ``N m``, ``(N*m)/rad``,
``degC``): the result is the same :class:`Quantity` either way, so quantities from both
sources multiply and compare with each other. tests/test_units_table.py checks that every
entry of the table, with every prefix and in products and quotients, gives exactly what
pint gives (magnitude, base units, dimension and the label phc prints), and that the table
is used only where pint is not imported.

A :class:`Quantity` holds what phc's checks read of a pint quantity in base units: its
magnitude (the unit's scale, 0.001 for ``mm``), its base units and their dimension, products
and powers; its unit text is written as pint's compact format ``~C`` writes it.
"""

from __future__ import annotations

import re
from typing import Mapping, Optional

__all__ = ["ONE", "PREFIXES", "UNITS", "Quantity", "Units", "from_pint", "parse_table"]

_BASE: dict[str, tuple[str, Optional[str]]] = {
    "meter": ("m", "[length]"), "kilogram": ("kg", "[mass]"), "second": ("s", "[time]"),
    "ampere": ("A", "[current]"), "kelvin": ("K", "[temperature]"), "mole": ("mol", "[substance]"),
    "candela": ("cd", "[luminosity]"), "radian": ("rad", None),
}
"""pint's base units of the SI: name -> (symbol, dimension); the radian is dimensionless."""

UNITS: dict[str, tuple[float, Mapping[str, int]]] = {
    "m": (1, {"meter": 1}),
    "g": (0.001, {"kilogram": 1}),
    "s": (1, {"second": 1}),
    "A": (1, {"ampere": 1}),
    "K": (1, {"kelvin": 1}),
    "mol": (1, {"mole": 1}),
    "rad": (1, {"radian": 1}),
    "N": (1, {"kilogram": 1, "meter": 1, "second": -2}),
    "J": (1, {"kilogram": 1, "meter": 2, "second": -2}),
    "W": (1, {"kilogram": 1, "meter": 2, "second": -3}),
    "Pa": (1, {"kilogram": 1, "meter": -1, "second": -2}),
    "V": (1, {"kilogram": 1, "meter": 2, "second": -3, "ampere": -1}),
    "Ohm": (1, {"kilogram": 1, "meter": 2, "second": -3, "ampere": -2}),
    "ohm": (1, {"kilogram": 1, "meter": 2, "second": -3, "ampere": -2}),
    "F": (1, {"ampere": 2, "second": 4, "kilogram": -1, "meter": -2}),
    "H": (1, {"kilogram": 1, "meter": 2, "second": -2, "ampere": -2}),
    "C": (1, {"ampere": 1, "second": 1}),
    "Wb": (1, {"kilogram": 1, "meter": 2, "second": -2, "ampere": -1}),
    "T": (1, {"kilogram": 1, "second": -2, "ampere": -1}),
    "Hz": (1, {"second": -1}),
}
"""The SI symbols phc reads itself: symbol -> (scale, base units). ``kg`` is ``k`` + ``g``."""

PREFIXES: dict[str, float] = {"n": 1e-9, "u": 1e-6, "m": 1e-3, "c": 1e-2, "k": 1e3, "M": 1e6, "G": 1e9}
"""SI prefixes the table takes (``µ`` is written ``u`` before parsing, as for pint)."""

_TERM = re.compile(r"([A-Za-z]+)(?:(?:\^|\*\*)(-?[0-9]+))?")
_SPLIT = re.compile(r"(\*\*|\*|/|\^)")


class _Container(dict):
    """Base units or dimensions: name -> exponent, hashable, equal as mappings (as pint's)."""

    __slots__ = ("_hash",)

    def __hash__(self):
        try:
            return self._hash
        except AttributeError:
            self._hash = hash(frozenset(self.items()))
            return self._hash

    def __setitem__(self, key, value):  # frozen once built
        raise TypeError("unit containers are immutable")

    def __reduce__(self):  # copied and pickled through _build, not item by item
        return _build, (type(self), tuple(self.items()), getattr(self, "symbols", None))


class Units(_Container):
    """Base units of a :class:`Quantity`, formatted (``~C``) as pint's compact short format."""

    __slots__ = ("symbols",)

    def __format__(self, spec: str) -> str:
        symbols = getattr(self, "symbols", None) or {}
        # pint: numerator and denominator each sorted by unit name, exponents by `{:n}`
        top = sorted((name, power) for name, power in self.items() if power >= 0)
        bottom = sorted((name, power) for name, power in self.items() if power < 0)

        def term(name, power):
            symbol = symbols.get(name) or _BASE.get(name, (name,))[0]
            return symbol if abs(power) == 1 else f"{symbol}**{format(abs(power), 'n')}"

        num = "*".join(term(n, p) for n, p in top)
        den = [term(n, p) for n, p in bottom]
        if not num and not den:
            return ""
        return "/".join([num or "1", *den])


def _build(kind, items, symbols=None):
    out = kind()
    for name, power in items:
        if power != 0:
            dict.__setitem__(out, name, power)
    if symbols is not None:
        out.symbols = symbols
    return out


def _dimensionality(units: Mapping, dims: Optional[Mapping] = None) -> _Container:
    total: dict = {}
    for name, power in units.items():
        dim = _BASE[name][1] if name in _BASE else (dims or {}).get(name)
        if dim is not None:
            total[dim] = total.get(dim, 0) + power
    return _build(_Container, total.items())


class Quantity:
    """A unit in base units: ``magnitude`` (its scale), ``units`` and ``dimensionality``."""

    __slots__ = ("magnitude", "units", "dimensionality", "_dims")

    def __init__(self, magnitude, units: Units, dimensionality: _Container, dims: Optional[Mapping] = None):
        self.magnitude, self.units, self.dimensionality = magnitude, units, dimensionality
        self._dims = dims  # dimension of each base unit outside the SI table (from pint)

    def __repr__(self) -> str:
        return f"<Quantity({self.magnitude}, '{self.units:~C}')>"

    def _merged(self, other: "Quantity"):
        symbols = {**(getattr(self.units, "symbols", None) or {}), **(getattr(other.units, "symbols", None) or {})}
        dims = {**(self._dims or {}), **(other._dims or {})}
        return symbols or None, dims or None

    def __mul__(self, other):
        if isinstance(other, Quantity):
            total = dict(self.units)
            for name, power in other.units.items():
                total[name] = total.get(name, 0) + power
            symbols, dims = self._merged(other)
            units = _build(Units, total.items(), symbols)
            return Quantity(self.magnitude * other.magnitude, units, _dimensionality(units, dims), dims)
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return Quantity(self.magnitude * other, self.units, self.dimensionality, self._dims)
        return NotImplemented

    __rmul__ = __mul__

    def __pow__(self, exponent):
        if not isinstance(exponent, (int, float)) or isinstance(exponent, bool):
            return NotImplemented
        units = _build(Units, ((n, p * exponent) for n, p in self.units.items()), getattr(self.units, "symbols", None))
        return Quantity(self.magnitude ** exponent, units, _dimensionality(units, self._dims), self._dims)

    def __truediv__(self, other):
        if isinstance(other, Quantity):  # as pint: the magnitudes divided, the exponents subtracted
            total = dict(self.units)
            for name, power in other.units.items():
                total[name] = total.get(name, 0) - power
            symbols, dims = self._merged(other)
            units = _build(Units, total.items(), symbols)
            return Quantity(self.magnitude / other.magnitude, units, _dimensionality(units, dims), dims)
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return Quantity(self.magnitude / other, self.units, self.dimensionality, self._dims)
        return NotImplemented

    def __eq__(self, other):
        return (isinstance(other, Quantity) and self.magnitude == other.magnitude and self.units == other.units)

    def __hash__(self):
        return hash((self.magnitude, self.units))

    def unit_items(self):
        return tuple(self.units.items())


ONE = Quantity(1, _build(Units, ()), _build(_Container, ()))
"""The dimensionless 1."""


def _term(text: str) -> Optional[tuple[float, Mapping[str, int]]]:
    if text in UNITS:
        return UNITS[text]
    if text[:1] in PREFIXES and text[1:] in UNITS:
        scale, base = UNITS[text[1:]]
        return PREFIXES[text[0]] * scale, base
    return None


def parse_table(text: str) -> Optional[Quantity]:
    """`text` (µ already written u) from the table: products and quotients of table units with
    integer powers (``N*m/rad``, ``kg*m^2``, ``kN/mm``, ``1/s``), or None for anything else
    (pint reads it then)."""
    if text == "1":
        return ONE
    parts = _SPLIT.split(text)
    total: dict = {}
    magnitude = 1
    sign = 1
    i = 0
    while i < len(parts):
        piece = parts[i]
        if i == 0 and piece == "1" and len(parts) > 1 and parts[1] == "/":
            i += 1
            continue
        if i > 0:
            if piece not in ("*", "/"):
                return None
            sign = -1 if piece == "/" else 1
            i += 1
            piece = parts[i] if i < len(parts) else ""
        power = 1
        if i + 2 < len(parts) and parts[i + 1] in ("^", "**"):
            exponent = parts[i + 2]
            if not re.fullmatch(r"-?[0-9]{1,2}", exponent):
                return None
            power = int(exponent)
            i += 2
        found = _term(piece)
        if found is None:
            return None
        scale, base = found
        power *= sign
        magnitude = magnitude * scale ** power
        for name, p in base.items():
            total[name] = total.get(name, 0) + p * power
        i += 1
    units = _build(Units, total.items())
    return Quantity(magnitude, units, _dimensionality(units))


def from_pint(quantity, registry) -> Quantity:
    """A :class:`Quantity` of a pint quantity in base units of `registry` (a unit outside
    the table)."""
    items = list(quantity.unit_items())
    symbols = {name: registry.get_symbol(name) for name, _ in items if name not in _BASE}
    dims = {}
    for name, _ in items:
        if name not in _BASE:
            own = dict(registry.get_dimensionality(name))
            if len(own) > 1 or (own and next(iter(own.values())) != 1):
                raise ValueError(f"base unit {name} of pint has a compound dimension")
            dims[name] = next(iter(own)) if own else None
    units = _build(Units, items, symbols or None)
    return Quantity(quantity.magnitude, units, _dimensionality(units, dims), dims or None)
