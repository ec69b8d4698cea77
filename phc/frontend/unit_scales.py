"""One system of units per model: the scales of its fields' units, solved (phc.frontend.units).

:func:`scale_terms` (how a component field's scale follows from the model's time unit and
its domains' effort and flow units), :class:`ScaleSystem` (the relations of all fields
solved in whole powers of ten; PHC-E172 where a field contradicts them),
:func:`scale_factor`, :func:`domain_scale` and :func:`time_scale`. Moved out of
:mod:`phc.frontend.units`, which imports them and keeps them importable; docs/units.md explains
the rules.
"""

from __future__ import annotations

from typing import Mapping, Optional


# -- scales: one system of units per model ------------------------------------------------
#
# phc does not convert units, so the numbers of a model must all be in one system of units.
# The system has a time unit and, for each port domain, an effort and a flow unit; each is
# its SI unit times a power of ten (s or ms; N or kN; m/s or mm/ms; Pa or MPa; ...). A
# component field whose dimension the component knows is a product of these (a spring's
# `k` is effort/(flow·time)), so its declared unit fixes a relation between their scales:
# `k` in N/mm says log10(effort) - log10(flow) - log10(time) = 3. The relations of all
# fields must have one solution in whole powers of ten; a field whose unit contradicts the
# others (N/mm beside kg: k·x in kN against ṗ in N) or is not a power of ten of its SI unit
# (rpm: 0.1047 rad/s) is refused (PHC-E172), with the factor. docs/units.md explains it.

_TIME = "T"
_TIME_CANDIDATES = (0, -3, 3, -6, 6, -9, 9, -12, 12, -1, 1, -2, 2, -4, 4, -5, 5, -7, 7, -8, 8, -10, 10, -11, 11)
"""Time scales tried (log10 of the model's time unit in s), the second first."""


def scale_terms(comp, domains: Mapping[str, str]) -> dict[str, dict]:
    """For each field of `comp` whose scale follows from the model's unit system:
    ``{field: {variable: exponent}}`` where a variable is ``"T"`` (the time unit) or
    ``("E"|"F", domain)`` (a domain's effort or flow unit). Empty without pint or where a
    field's unit is not a product of these (the beams' SI fields, the generic domain)."""
    from phc.frontend.units import _type_units, have_pint

    if not have_pint():
        return {}
    units = _type_units(comp)
    if units is None:
        return {}
    # the same for every spring of a chain: computed once per kind (as phc.frontend.units.expected_fields)
    key = (getattr(comp, "type", None), id(units), frozenset(domains.items()),
           tuple(getattr(comp, eu.field, None) is not None for eu in units.element or ()))
    found = _TERMS.get(key)
    if found is None:
        if len(_TERMS) >= 1024:
            _TERMS.clear()
        found = _TERMS[key] = (units, _scale_terms(comp, domains, units))
    return {field: dict(terms) for field, terms in found[1].items()}


_TERMS: dict = {}
"""scale_terms by (type, port domains, which of its element fields are given)."""


def _scale_terms(comp, domains: Mapping[str, str], units) -> dict[str, dict]:
    from phc.frontend.units import _element_fields, domain_units

    out: dict[str, dict] = {}
    if units.element:
        doms = set(domains.values())
        if len(doms) != 1 or domain_units(next(iter(doms))) is None:
            return out
        dom = next(iter(doms))
        names = {"e": ("E", dom), "f": ("F", dom), "s": _TIME}
        for field, num, den, _ in _element_fields(comp, units):
            terms: dict = {}
            for text, sign in ((num, 1), (den, -1)):
                for part in text.split("*"):
                    if part in names:
                        terms[names[part]] = terms.get(names[part], 0) + sign
            out[field] = {k: v for k, v in terms.items() if v}
        return out
    if units.ratio is not None and {"a", "b"} <= domains.keys():
        if domain_units(domains["a"]) is None or domain_units(domains["b"]) is None:
            return out
        top = (units.ratio[0].upper(), domains["b"])
        bottom = (units.ratio[1].upper(), domains["a"])
        out["ratio"] = {} if top == bottom else {top: 1, bottom: -1}
    return out


def scale_factor(dim, want) -> float:
    """The factor between a quantity and the SI quantity of the same dimension: 1000 for
    N/mm against N/m."""
    return float(dim.magnitude) / float(want.magnitude)


class ScaleSystem:
    """The model's unit system, solved from the scales of its fields (see above).

    :meth:`add` takes one relation (``{variable: exponent}`` and the field's log10 scale)
    and returns None when it agrees with the relations added so far, else the log10 scale
    the field must have with them (the relation is then left out)."""

    def __init__(self) -> None:
        self.rows: list[tuple[dict, float]] = []
        self._solution: Optional[dict] = {}
        self._seen: set = set()

    def variables(self, rows=None) -> list:
        seen: dict = {}
        for coeffs, _ in (self.rows if rows is None else rows):
            for var in coeffs:
                if var != _TIME:
                    seen.setdefault(var, None)
        return sorted(seen, key=str)

    @staticmethod
    def _solve(rows, variables, time: int):
        """A solution with the time scale `time`, or None."""
        import numpy as np

        if not rows:
            return {}
        if not variables:
            ok = all(abs(b - c.get(_TIME, 0) * time) < 1e-6 for c, b in rows)
            return {} if ok else None
        a = np.array([[c.get(v, 0) for v in variables] for c, _ in rows], dtype=float)
        rhs = np.array([b - c.get(_TIME, 0) * time for c, b in rows], dtype=float)
        # Not phc.simulation.minnorm's dense_min_norm: this runs while `phc validate` reads a
        # model, which does not import phc.simulation otherwise (importing it for this solve
        # cost 0.5 to 0.9 s, measured). Small integer exponents: the rank is clear-cut, and
        # numpy's threshold decides it as gelsy's would.
        x, *_ = np.linalg.lstsq(a, rhs, rcond=None)
        if np.max(np.abs(a @ x - rhs)) > 1e-6:
            return None
        return dict(zip(variables, x))

    def _feasible(self, rows):
        """The SI-nearest solution in whole powers of ten: the first time scale that works
        (the second first), then every other scale 0 where the relations leave it free."""
        variables = self.variables(rows)
        for time in _TIME_CANDIDATES:
            if self._solve(rows, variables, time) is None:
                continue
            fixed = list(rows)
            for var in variables:
                trial = fixed + [({var: 1}, 0.0)]
                if self._solve(trial, variables, time) is not None:
                    fixed = trial
            solution = self._solve(fixed, variables, time)
            solution = {k: float(round(v)) for k, v in solution.items()}
            solution[_TIME] = float(time)
            return solution
        return None

    def predicted(self, coeffs: dict) -> float:
        """log10 of the scale a field with these exponents has in the system solved so far."""
        sol = self._solution or {}
        return sum(e * sol.get(v, 0.0) for v, e in coeffs.items())

    def add(self, coeffs: dict, scale: float) -> Optional[float]:
        if abs(scale - round(scale)) > 1e-9:  # not a power of ten of its SI unit (rpm, inch, min)
            return self.predicted(coeffs)
        scale = float(round(scale))
        key = (tuple(sorted(coeffs.items(), key=str)), scale)
        if key in self._seen:  # a relation already in the system (a chain of equal masses)
            return None
        trial = self.rows + [(coeffs, scale)]
        solution = self._feasible(trial)
        if solution is None:
            return self.predicted(coeffs)
        self.rows, self._solution = trial, solution
        self._seen.add(key)
        return None

    def solution(self) -> dict:
        """log10 of each unit of the solved system: ``"T"`` and ``("E"|"F", domain)``;
        what no field fixes is SI (0)."""
        return dict(self._solution or {})


def domain_scale(scales: Optional[Mapping], domain: str, which: str) -> float:
    """log10 of the model's unit of a domain's effort (`which` "E") or flow ("F")."""
    return float((scales or {}).get((which, domain), 0.0))


def time_scale(scales: Optional[Mapping]) -> float:
    """log10 of the model's time unit in seconds (0: s, -3: ms)."""
    return float((scales or {}).get(_TIME, 0.0))
