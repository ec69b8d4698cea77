"""The value syntax of a parameter study: ``NAME=SPEC`` on the command line, and the
``sweep:`` section of a scene file (:class:`SweepSpec`).

A SPEC is one of

* a number, ``68.27`` — one value (the same as ``phc simulate --param NAME=VALUE``);
* a list, ``1,2,5`` (or a YAML list ``[1, 2, 5]`` in a scene);
* a linear grid ``A:B:N`` — N values from A to B, ends included;
* a logarithmic grid ``log:A:B:N`` (0 < A, B);
* a distribution, sampled ``--samples N`` times by Latin-hypercube (default) or plain
  random sampling: ``uniform:A:B``, ``normal:MEAN:STD``, ``loguniform:A:B`` (0 < A < B;
  also written ``log-uniform``).

Grid values form a product over the parameters; the sampled parameters form N points,
and the whole design is the grid × the samples. Parsing is plain string splitting and
``float()``: nothing here is evaluated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Annotated, Literal, Optional, Union

from pydantic import AfterValidator, Field, StrictFloat, StrictInt

from phc.errors import SpecError
from phc.spec.base import SpecModel

MAX_VALUES = 100_000
"""Most values one grid may have (and most samples)."""
DISTRIBUTIONS = ("uniform", "normal", "loguniform")
SAMPLING = ("lhs", "random")
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*(\[[0-9]+\])?")
"""A swept name: a model parameter (nested by dotted name), ``accuracy.rtol``,
``accuracy.atol``, ``accuracy.step`` or ``accuracy.mesh.COMPONENT``."""


@dataclass(frozen=True)
class Axis:
    """One swept parameter: grid values, or a distribution to sample."""

    name: str
    text: str
    """The SPEC as written."""
    values: tuple[float, ...] = ()
    """Grid or list values (empty for a distribution)."""
    distribution: Optional[str] = None
    """`uniform`, `normal` or `loguniform` (None for grid values)."""
    a: float = math.nan
    """Lower bound, or the mean of a normal distribution."""
    b: float = math.nan
    """Upper bound, or the standard deviation of a normal distribution."""
    log: bool = False
    """Logarithmic spacing (a `log:` grid or `loguniform`): plots use a log axis."""

    @property
    def sampled(self) -> bool:
        return self.distribution is not None

    def describe(self) -> str:
        if self.sampled:
            return f"{self.distribution}({self.a:g}, {self.b:g})"
        if len(self.values) == 1:
            return f"{self.values[0]:g}"
        spread = f"{len(self.values)} values {min(self.values):g} … {max(self.values):g}"
        return spread + (" (log)" if self.log else "")


_FORMS = ("write a number, a list `1,2,5`, a grid `A:B:N` or `log:A:B:N`, or a distribution "
          "`uniform:A:B`, `normal:MEAN:STD`, `loguniform:A:B`")


def _number(text: str, what: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SpecError(f"`{spec}`: {what} `{text.strip()}` is not a number; {_FORMS}") from None
    if not math.isfinite(value):
        raise SpecError(f"`{spec}`: {what} must be a finite number, got `{text.strip()}`")
    return value


def _count(text: str, spec: str) -> int:
    n = _number(text, "the number of values", spec)
    if n != int(n) or not 1 <= n <= MAX_VALUES:
        raise SpecError(f"`{spec}`: the number of values must be a whole number from 1 to {MAX_VALUES}, "
                        f"got `{text.strip()}`")
    return int(n)


def parse_spec(name: str, spec: Union[str, int, float, list]) -> Axis:
    """Read one SPEC (a string as on the command line, or a number or list from YAML).

    Raises
    ------
    SpecError
        With a message naming the SPEC and the accepted forms.
    """
    if isinstance(spec, bool):
        raise SpecError(f"`{spec}` is not a number; {_FORMS}")
    if isinstance(spec, (int, float)):
        return Axis(name, repr(spec), (_number(repr(spec), "the value", repr(spec)),))
    if isinstance(spec, (list, tuple)):
        if not spec:
            raise SpecError(f"the list of values is empty; {_FORMS}")
        if len(spec) > MAX_VALUES:
            raise SpecError(f"more than {MAX_VALUES} values")
        values = tuple(_number(str(v), "the value", str(list(spec))) for v in spec)
        return Axis(name, ",".join(str(v) for v in spec), values)
    text = str(spec).strip()
    if not text:
        raise SpecError(f"the value is empty; {_FORMS}")
    head, sep, rest = text.partition(":")
    head = head.strip().lower()
    parts = rest.split(":") if sep else []
    if head in ("uniform", "normal", "loguniform", "log-uniform"):
        kind = "loguniform" if head == "log-uniform" else head
        if len(parts) != 2:
            form = "MEAN:STD" if kind == "normal" else "A:B"
            raise SpecError(f"`{text}`: `{head}` takes two numbers, `{head}:{form}`")
        a, b = (_number(p, "the bound" if kind != "normal" else "the mean/std", text) for p in parts)
        if kind == "normal" and not b > 0:
            raise SpecError(f"`{text}`: the standard deviation must be positive")
        if kind != "normal" and not a < b:
            raise SpecError(f"`{text}`: the lower bound must be below the upper bound")
        if kind == "loguniform" and not a > 0:
            raise SpecError(f"`{text}`: log-uniform bounds must be positive")
        return Axis(name, text, (), kind, a, b, log=kind == "loguniform")
    if head == "log":
        if len(parts) != 3:
            raise SpecError(f"`{text}`: a logarithmic grid is `log:A:B:N`")
        a, b = (_number(p, "the end", text) for p in parts[:2])
        n = _count(parts[2], text)
        if not (a > 0 and b > 0):
            raise SpecError(f"`{text}`: the ends of a logarithmic grid must be positive")
        values = [a] if n == 1 else [math.exp(math.log(a) + (math.log(b) - math.log(a)) * i / (n - 1))
                                     for i in range(n)]
        if n > 1:
            values[-1] = b
        return Axis(name, text, tuple(values), log=True)
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise SpecError(f"`{text}`: a grid is `A:B:N` (N values from A to B); {_FORMS}")
        a, b = (_number(p, "the end", text) for p in parts[:2])
        n = _count(parts[2], text)
        values = [a] if n == 1 else [a + (b - a) * i / (n - 1) for i in range(n)]
        if n > 1:
            values[-1] = b
        return Axis(name, text, tuple(values))
    items = [s for s in text.split(",")]
    if len(items) > MAX_VALUES:
        raise SpecError(f"`{text[:40]}…`: more than {MAX_VALUES} values")
    if any(not s.strip() for s in items):
        raise SpecError(f"`{text}`: an empty entry in the list; {_FORMS}")
    return Axis(name, text, tuple(_number(s, "the value", text) for s in items))


def check_name(name: str) -> str:
    if not NAME_RE.fullmatch(name):
        shown = f"`{name}`" if name.isprintable() else repr(name)
        raise ValueError(f"{shown} is not a parameter name: write a model parameter (`EI`, nested `sub.k`) or "
                         "`accuracy.rtol`, `accuracy.atol`, `accuracy.step`, `accuracy.mesh.COMPONENT`")
    return name


def _check_spec(text: str) -> str:
    parse_spec("", text)  # SpecError is a ValueError: pydantic locates it at the entry
    return text


SweepName = Annotated[str, AfterValidator(check_name)]
SweepValue = Union[StrictInt, StrictFloat, Annotated[list[Union[StrictInt, StrictFloat]], Field(min_length=1)],
                   Annotated[str, AfterValidator(_check_spec)]]


class SweepSpec(SpecModel):
    """The parameter study of ``phc sweep SCENE.yaml`` (options on the command line add to
    and override it)."""

    parameters: dict[SweepName, SweepValue] = {}
    """Swept values per name: a number, a list, a grid `"A:B:N"`, `"log:A:B:N"`, or a
    distribution `"uniform:A:B"`, `"normal:MEAN:STD"`, `"loguniform:A:B"`. Names are model
    parameters, `accuracy.rtol`, `accuracy.atol`, `accuracy.step` or
    `accuracy.mesh.COMPONENT`."""
    samples: Optional[int] = Field(None, ge=1, le=MAX_VALUES)
    """Number of samples of the distributions (required when one is given)."""
    seed: int = 0
    """Seed of the sampler: the same seed gives the same points."""
    sampling: Literal["lhs", "random"] = "lhs"
    """Latin-hypercube (`lhs`: each of the N equal-probability strata of every parameter
    is hit once) or independent random sampling."""


__all__ = ["Axis", "DISTRIBUTIONS", "MAX_VALUES", "SAMPLING", "SpecError", "SweepSpec", "check_name", "parse_spec"]
