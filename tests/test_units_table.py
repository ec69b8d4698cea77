"""The table of common SI units (phc.frontend.si_units) against pint.

phc reads SI symbols with prefixes, products, quotients and integer powers from its own
table, so that a model in SI units is checked without importing pint or building its
registry (a cold `phc compile` spends about a second on those). Everything the table reads
must be exactly what pint reads: the scale (compared with ==, since a scale can end up as a
factor in generated code), the base units, the dimension and the label phc prints; units
outside the table still go to pint, and quantities from both sources compute together.
"""

from __future__ import annotations

import copy
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

pint = pytest.importorskip("pint")

from phc.errors import UnitError  # noqa: E402
from phc.frontend import si_units  # noqa: E402
from phc.frontend.units import _registry, parse_unit, unit_label  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

COMPOUNDS = ("N*m", "N/m", "N*s/m", "kg*m^2", "kg*m**2", "m^3/s", "kN/mm", "N/mm", "kg/m^3", "1/s", "m/s^2",
             "N*m/rad", "N*m*s/rad", "Pa*s/m^3", "m^3/Pa", "kg/m^4", "J/K", "K/W", "N*m/A", "N/A", "mm^2",
             "mm^4", "g/mm^3", "N/mm^2", "kN*m", "kg*m^2/rad", "N*s/m^2", "N*m^2*s", "s^-1", "m^-2", "m/s/s",
             "m/s*kg", "mg", "ug", "kg/m", "GPa*mm^4", "g*mm^2", "cm^3", "mm^3/s", "kg*mm^2", "uF", "mH",
             "kOhm", "V/A", "A*s", "W/K", "mol/s", "rad/s^2", "1/mm", "kHz", "MPa*mm^2", "ms^2", "1")


def _pint(text: str):
    ureg = _registry()
    return si_units.from_pint((1 * ureg.parse_units(text)).to_base_units(), ureg), \
        (1 * ureg.parse_units(text)).to_base_units()


def _model_units() -> set[str]:
    """Every unit text the shipped models write (parameters and outputs)."""
    import yaml

    found: set[str] = set()

    def walk(node):
        if isinstance(node, dict):
            for key, value in node.items():
                if key == "unit" and isinstance(value, (str, int)):
                    found.add(str(value))
                walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    for path in sorted((ROOT / "models").rglob("*.yaml")):
        walk(yaml.safe_load(path.read_text(encoding="utf-8")))
    return found


def _same(text: str) -> None:
    mine = si_units.parse_table(text)
    assert mine is not None, f"{text} is not read by the table"
    ours, theirs = _pint(text)
    assert mine.magnitude == theirs.magnitude, (text, mine.magnitude, theirs.magnitude)
    assert dict(mine.units) == dict(theirs.unit_items()), text
    assert dict(mine.dimensionality) == dict(theirs.dimensionality), text
    assert f"{mine.units:~C}" == f"{theirs.units:~C}", text
    assert unit_label(mine) == unit_label(ours), text
    assert mine.units == ours.units and hash(mine.units) == hash(ours.units), text


@pytest.mark.parametrize("prefix", ["", *si_units.PREFIXES])
def test_every_table_unit_with_every_prefix_is_read_as_pint_reads_it(prefix):
    for name in si_units.UNITS:
        _same(prefix + name)


@pytest.mark.parametrize("text", COMPOUNDS)
def test_products_quotients_and_powers_are_read_as_pint_reads_them(text):
    _same(text)


def test_the_shipped_models_units_that_the_table_reads_are_pints():
    units = _model_units()
    assert units, "no unit found in models/"
    read = [u for u in units if si_units.parse_table(u.replace("µ", "u").replace("μ", "u")) is not None]
    assert len(read) >= len(units) // 2  # the table is for the common case: most units a model writes
    for text in read:
        _same(text.replace("µ", "u").replace("μ", "u"))


@pytest.mark.parametrize("text", ["rpm", "deg", "N m", "(N*m)/rad", "m²", "N·m", "kg*m^(2)", "min", "h"])
def test_text_outside_the_table_goes_to_pint(text):
    assert si_units.parse_table(text) is None
    quantity = parse_unit(text)
    ours, theirs = _pint(text.replace("·", "*") if text == "N·m" else text)
    assert quantity.magnitude == theirs.magnitude
    assert quantity.units == ours.units and quantity.dimensionality == ours.dimensionality


def test_quantities_from_the_table_and_from_pint_compute_together_as_pints_do():
    ureg = _registry()
    pairs = [("rpm", "s"), ("N*m", "deg"), ("kN/mm", "min"), ("mm", "h")]
    for a, b in pairs:
        qa, qb = parse_unit(a), parse_unit(b)
        pa = (1 * ureg.parse_units(a)).to_base_units()
        pb = (1 * ureg.parse_units(b)).to_base_units()
        for mine, theirs in ((qa * qb, pa * pb), (qa / qb, pa / pb), (qb / qa, pb / pa), (qa ** 2.0, pa ** 2.0),
                             (qb ** -1.0, pb ** -1.0), (qa * 1000.0, pa * 1000.0)):
            ref = si_units.from_pint(theirs, ureg)
            assert mine.magnitude == theirs.magnitude, (a, b)
            assert mine.units == ref.units and dict(mine.dimensionality) == dict(theirs.dimensionality), (a, b)
            assert f"{mine.units:~C}" == f"{theirs.units:~C}", (a, b)


def test_arithmetic_on_table_units_is_pints():
    ureg = _registry()
    for a in ("N", "mm", "kN/mm", "g", "V", "F"):
        for b in ("m", "ms", "kg*m^2", "A", "1"):
            qa, qb = si_units.parse_table(a), si_units.parse_table(b)
            pa = (1 * ureg.parse_units(a)).to_base_units()
            pb = (1 * ureg.parse_units(b)).to_base_units()
            for mine, theirs in ((qa * qb, pa * pb), (qa / qb, pa / pb), (qa ** 0.5, pa ** 0.5)):
                assert mine.magnitude == theirs.magnitude, (a, b)
                assert dict(mine.units) == dict(theirs.unit_items()), (a, b)
                assert dict(mine.dimensionality) == dict(theirs.dimensionality), (a, b)


def test_unknown_and_offset_units_are_refused_as_before():
    with pytest.raises(UnitError, match="unknown unit `Nw`"):
        parse_unit("Nw")
    with pytest.raises(UnitError, match="offset"):
        parse_unit("degC")
    with pytest.raises(UnitError, match="cannot read unit `N\\*`"):
        parse_unit("N*")  # not the table's: pint's parser (which asserts on it) and phc's message


def test_quantities_copy_and_pickle():
    for text in ("kN/mm", "rpm", "1"):
        q = parse_unit(text)
        for other in (pickle.loads(pickle.dumps(q)), copy.deepcopy(q)):
            assert other == q and other.dimensionality == q.dimensionality
            assert f"{other.units:~C}" == f"{q.units:~C}"
    with pytest.raises(TypeError):
        parse_unit("N").units["meter"] = 2


def test_a_model_in_si_units_is_checked_without_importing_pint():
    code = ("import sys, phc\n"
            "from phc.frontend.units import parse_unit, unit_label\n"
            "q = parse_unit('N*s/m') * parse_unit('m/s')\n"
            "print(unit_label(q), 'pint' in sys.modules)\n"
            "parse_unit('rpm')\n"
            "print('pint' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert done.stdout.split() == ["N", "False", "True"]
