"""The compiled-model contract: what a run needs of a model once it is compiled, as one
frozen, JSON-serializable value beside the generated module.

Input: the compiler's output (built by :func:`phc.pipeline.describe` from the assembled
:class:`~phc.ir.dae.Dae`, the generated module and the scene). Output: a
:class:`ModelDescription` — the model's name, its variables' units, the labels of its
equations and invariants with their places in the model file, the simulation options,
the initial values (evaluated at the default parameters, with the parameters each is
written in), the outputs with where they are written, what a scene left out, and the
certificate's verdict.

:func:`phc.simulate` reads the description and the module, nothing else of a compiled
model (the assembled :class:`~phc.ir.dae.Dae` is needed only to re-evaluate an initial value
written in a parameter that a run overrides, and to build a compiled backend later).
The cached front end of the command line (:mod:`phc.codegen.fastpath`) stores exactly
:meth:`ModelDescription.to_json` beside the generated source and loads it with
:meth:`ModelDescription.from_json` into a :class:`~phc.codegen.compiled.CompiledModel`.

Every mapping in a description is read-only (a :class:`types.MappingProxyType` over a
private copy) and every sequence a tuple, the equations a read-only :class:`LabelledRows`:
``compiled.options["rtol"] = 0.5`` raises ``TypeError`` instead of changing the next run. A description pickles through its JSON
text. This module imports nothing beyond the standard library.
"""

from __future__ import annotations

import json
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping, Optional

FORMAT = 1
"""Version of the JSON layout (:meth:`ModelDescription.to_json`)."""


def freeze(value: Any) -> Any:
    """`value` with every mapping made a read-only copy and every list or tuple a tuple."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: freeze(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    return value


def thaw(value: Any) -> Any:
    """A plain, mutable copy of a frozen value (dicts and lists), e.g. for ``json.dumps``."""
    if isinstance(value, Mapping):
        return {k: thaw(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class Place:
    """Where something is written: a file and a 1-based line and column."""

    file: str
    line: int
    col: int = 1

    def __str__(self) -> str:
        from phc.inert import inert

        return inert(f"{self.file}:{self.line}:{self.col}")

    @classmethod
    def of(cls, span) -> Optional["Place"]:
        """The place of any span with ``file``, ``line`` (and ``col``); None for None."""
        if span is None:
            return None
        return cls(str(span.file), int(span.line), int(getattr(span, "col", 1) or 1))


def _place_json(place: Optional[Place]) -> Optional[list]:
    return [place.file, place.line, place.col] if place is not None else None


def _place(data) -> Optional[Place]:
    return Place(str(data[0]), int(data[1]), int(data[2])) if data else None


def _rows(items) -> "LabelledRows":
    """The :class:`LabelledRows` of JSON ``[label, component, place]`` items, each distinct
    place made once."""
    made: dict = {}

    def place(data):
        key = tuple(data) if data else None
        if key not in made:
            made[key] = _place(data)
        return made[key]

    return LabelledRows((str(lab), str(comp), place(s)) for lab, comp, s in items)


@dataclass(frozen=True)
class Labelled:
    """An equation or invariant of the compiled model: its label, the component it comes
    from and where it is written."""

    label: str
    component: str = ""
    span: Optional[Place] = None


class LabelledRows(Sequence):
    """The equations of a compiled model as a read-only sequence of :class:`Labelled`, each
    made when it is read: the labels and components as tuples of strings (the strings shared
    with whoever made them), the places as indices into the few distinct places (the rows of a
    mesh share one). A mesh of 10⁵ Euler–Bernoulli elements has 8·10⁵ rows: a Labelled object
    for each held about 120 MiB (issue 35); these hold about 16 bytes a row. Equal to another
    sequence of the same Labelled (a tuple of them included)."""

    __slots__ = ("labels", "components", "_where", "_places")

    def __init__(self, items: Iterable = ()) -> None:
        """From ``Labelled`` items or ``(label, component, place)`` triples (place a
        :class:`Place` or None)."""
        labels, components, where, places = [], [], array("l"), []
        index: dict = {}
        last, last_i = object(), -1
        for item in items:
            label, component, place = ((item.label, item.component, item.span) if isinstance(item, Labelled)
                                       else item)
            if place is not last:  # consecutive rows mostly share one Place object
                last, last_i = place, index.get(place)
                if last_i is None:
                    last_i = index[place] = len(places)
                    places.append(place)
            labels.append(label)
            components.append(component)
            where.append(last_i)
        self.labels, self.components = tuple(labels), tuple(components)
        self._where, self._places = where, tuple(places)

    def __len__(self) -> int:
        return len(self.labels)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return tuple(self[k] for k in range(*i.indices(len(self))))
        return Labelled(self.labels[i], self.components[i], self._places[self._where[i]])

    def __iter__(self):
        places, where = self._places, self._where
        for k, (label, component) in enumerate(zip(self.labels, self.components)):
            yield Labelled(label, component, places[where[k]])

    def __eq__(self, other) -> bool:
        if isinstance(other, LabelledRows):
            return (self.labels == other.labels and self.components == other.components
                    and all(a == b for a, b in zip(self.spans(), other.spans())))
        if isinstance(other, (tuple, list)):
            return len(other) == len(self) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def spans(self):
        """The place of each row, in order (None where not located)."""
        places = self._places
        return (places[k] for k in self._where)

    def __repr__(self) -> str:
        return f"LabelledRows({len(self)} rows)"


@dataclass(frozen=True)
class Connection:
    """A connection as written: the two ports, the label of its rows and its place."""

    a: str
    b: str
    label: str
    span: Optional[Place] = None


@dataclass(frozen=True)
class Initial:
    """An initial value of the model: its value at the default parameters, whether it is a
    guess, where it is written, and the parameters it is written in.

    `depends` lists those parameters (through derived ones, transitively): empty for a
    number, None when they are not known (then any parameter override may change it)."""

    name: str
    value: float
    guess: bool
    span: Optional[Place] = None
    depends: Optional[tuple[str, ...]] = ()


@dataclass(frozen=True)
class Verdict:
    """The certificate's verdict as compiling it reported it (:mod:`phc.checks.compiled`):
    its one-line summary and its report (``CompiledCertificate.to_dict()``)."""

    summary: str
    report: Mapping[str, Any]

    def __post_init__(self) -> None:
        object.__setattr__(self, "report", freeze(self.report))

    @property
    def certified(self) -> bool:
        return bool(self.report.get("certified", False))

    def to_dict(self) -> dict:
        """The report as a plain dict (a copy)."""
        return thaw(self.report)


@dataclass(frozen=True)
class SceneRef:
    """The scene a model was compiled for: its name and its `model:` entry as written."""

    name: str
    model: str


@dataclass(frozen=True)
class ModelDescription:
    """What a run needs of a compiled model besides its generated module.

    Attributes
    ----------
    name : str
        The compiled model's name (the scene's, for a scene).
    model : str
        The model's own name.
    n_states : int
        Number of states (without the energy accumulator).
    options : Mapping
        The simulation options (``t_start``, ``t_end``, ``n_out``, ``rtol``, ``atol``,
        ``max_steps``, ``solver``, ``max_order``, ``step``, ``nominal``), read-only.
    units : Mapping
        Unit labels of variables, outputs and ``H`` where known.
    equations : LabelledRows
        A read-only sequence of Labelled, in the order of the generated module's rows.
    invariants, velocity_invariants : tuple of Labelled
        In the order of the generated module's invariants.
    initial : tuple of Initial
        The model's initial values.
    outputs : tuple of str
        Output names, in the module's order.
    output_spans : Mapping
        Output name -> where it is written (None when not located).
    connections : tuple of Connection
        The connections as written (for messages naming a coupling row).
    left_out : tuple
        What a scene left out, as (component, what, why).
    sources : tuple of str
        The model files read, the model's own first.
    scene : SceneRef or None
        The scene it was compiled for.
    certificate : Verdict or None
        The certificate's verdict; None when compiled without it.

    Examples
    --------
    >>> import phc
    >>> from phc.codegen.description import ModelDescription
    >>> d = phc.compile_model("models/pendulum.yaml").description
    >>> ModelDescription.from_json(d.to_json()) == d
    True
    >>> d.options["rtol"] = 0.5
    Traceback (most recent call last):
    ...
    TypeError: 'mappingproxy' object does not support item assignment
    """

    name: str
    model: str
    n_states: int
    options: Mapping[str, Any]
    units: Mapping[str, str]
    equations: Sequence[Labelled]
    invariants: tuple[Labelled, ...]
    velocity_invariants: tuple[Labelled, ...]
    initial: tuple[Initial, ...]
    outputs: tuple[str, ...]
    output_spans: Mapping[str, Optional[Place]]
    connections: tuple[Connection, ...] = ()
    left_out: tuple[tuple[str, str, str], ...] = ()
    sources: tuple[str, ...] = ()
    scene: Optional[SceneRef] = None
    certificate: Optional[Verdict] = None

    def __post_init__(self) -> None:
        for f in ("options", "units", "output_spans"):
            object.__setattr__(self, f, freeze(getattr(self, f)))
        if not isinstance(self.equations, LabelledRows):
            object.__setattr__(self, "equations", LabelledRows(self.equations))
        for f in ("invariants", "velocity_invariants", "initial", "outputs", "connections", "sources"):
            object.__setattr__(self, f, tuple(getattr(self, f)))
        object.__setattr__(self, "left_out", tuple(tuple(x) for x in self.left_out))

    __hash__ = None  # type: ignore[assignment]  # read-only mappings are not hashable

    def __reduce__(self):
        """Pickled as its JSON text (read-only mappings do not pickle)."""
        return (ModelDescription.from_json, (self.to_json(),))

    # -- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """A plain dict of JSON types (:meth:`from_dict` reads it back)."""
        def labelled(items):
            return [[x.label, x.component, _place_json(x.span)] for x in items]

        equations = self.equations
        places = {id(p): _place_json(p) for p in equations._places}  # one list per distinct place

        return {
            "format": FORMAT, "name": self.name, "model": self.model, "n_states": self.n_states,
            "options": thaw(self.options), "units": thaw(self.units),
            "equations": [[label, component, places[id(place)]] for label, component, place
                          in zip(equations.labels, equations.components, equations.spans())],
            "invariants": labelled(self.invariants),
            "velocity_invariants": labelled(self.velocity_invariants),
            "initial": [[iv.name, iv.value, iv.guess, _place_json(iv.span),
                         list(iv.depends) if iv.depends is not None else None] for iv in self.initial],
            "outputs": list(self.outputs),
            "output_spans": {k: _place_json(v) for k, v in self.output_spans.items()},
            "connections": [[c.a, c.b, c.label, _place_json(c.span)] for c in self.connections],
            "left_out": [list(x) for x in self.left_out], "sources": list(self.sources),
            "scene": [self.scene.name, self.scene.model] if self.scene is not None else None,
            "certificate": ([self.certificate.summary, self.certificate.to_dict()]
                            if self.certificate is not None else None),
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> "ModelDescription":
        """The description :meth:`to_dict` wrote.

        Raises
        ------
        ValueError
            When `data` is of another format version or misses a field.
        """
        if data.get("format") != FORMAT:
            raise ValueError(f"a model description of format {data.get('format')!r}, expected {FORMAT}")
        try:
            def labelled(items):
                return tuple(Labelled(str(lab), str(comp), _place(s)) for lab, comp, s in items)

            scene, cert = data["scene"], data["certificate"]
            return cls(
                name=data["name"], model=data["model"], n_states=int(data["n_states"]), options=data["options"],
                units=data["units"], equations=_rows(data["equations"]), invariants=labelled(data["invariants"]),
                velocity_invariants=labelled(data["velocity_invariants"]),
                initial=tuple(Initial(str(n), float(v), bool(g), _place(s), tuple(d) if d is not None else None)
                              for n, v, g, s, d in data["initial"]),
                outputs=tuple(data["outputs"]),
                output_spans={k: _place(v) for k, v in data["output_spans"].items()},
                connections=tuple(Connection(a, b, lab, _place(s)) for a, b, lab, s in data["connections"]),
                left_out=tuple(tuple(x) for x in data["left_out"]), sources=tuple(data["sources"]),
                scene=SceneRef(*scene) if scene is not None else None,
                certificate=Verdict(cert[0], cert[1]) if cert is not None else None)
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"not a model description: {err}") from err

    def to_json(self) -> str:
        """The description as JSON text (NaN and infinities as JavaScript's literals)."""
        return json.dumps(self.to_dict(), allow_nan=True, sort_keys=True)

    @classmethod
    def from_json(cls, text: str | bytes) -> "ModelDescription":
        """The description :meth:`to_json` wrote (raises ValueError for anything else)."""
        return cls.from_dict(json.loads(text))


__all__ = ["Connection", "FORMAT", "Initial", "Labelled", "ModelDescription", "Place", "SceneRef", "Verdict",
           "freeze", "thaw"]
