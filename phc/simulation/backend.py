"""The contract every integrator (simulation backend) implements.

Input: a generated residual module, the full parameter vector, the output times and a
consistent start ``(y₀, ẏ₀)``, plus options. Output: a :class:`BackendRun`.

Like scipy's ``solve_ivp`` methods, each backend is a function with one signature::

    integrate(mod, p, t_out, y0, yp0, options, *, progress=None, names=None,
              nominal=None, events=None) -> BackendRun

where `options` is the run's :class:`~phc.options.RunOptions` (the one options object of
the model file, the scene, the command line and :func:`phc.simulate`; a backend reads the
fields it honours: `rtol`, `atol`, `max_order` for IDA, `step` for the fixed-step methods,
`max_steps` for all), wrapped in a :class:`Backend` that names it and says which options it
honours. A backend returns what it computed up to a failure (``success`` False,
``message`` saying when, why and what to try) rather than raising. Options are validated
once, when the :class:`~phc.options.RunOptions` is made; an option the chosen backend does
not use is reported with an :class:`IgnoredOptionWarning` instead of being dropped in
silence (a fixed-step method has no ``rtol``; IDA has no ``step``).
"""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
from dataclasses import dataclass, field, fields
from typing import Callable, Iterator, Optional

import numpy as np

from phc.errors import IgnoredOptionWarning  # defined with phc's other warnings, light to import


@dataclass
class BackendRun(Mapping):
    """What a backend returns: the outputs at the times it reached, and statistics.

    It is also a read-only mapping of its fields (``run["t"]``); :meth:`replace` makes the
    changed copies the drivers in :mod:`phc.simulation` combine pieces of a run with."""

    t: np.ndarray
    """Output times reached (a prefix of the requested ones when the run stopped early)."""
    y: np.ndarray
    """States at `t`, shape (len(t), N)."""
    yp: np.ndarray
    """Derivatives at `t`, shape (len(t), N)."""
    steps: int
    success: bool
    message: str
    cpu: float = 0.0
    nfev: int = 0
    njev: int = 0
    interrupted: bool = False
    conditioning: Optional[float] = None
    event: Optional[dict] = None
    """The switching function that stopped the run (``t``, ``y``, ``yp``, ``which``), when
    the backend watched switching functions (:mod:`phc.simulation.events`)."""
    events: list = field(default_factory=list)
    """The switches of a run with switching conditions, in order."""
    extra: dict = field(default_factory=dict)
    """Backend-specific statistics (kept, not interpreted)."""

    @classmethod
    def from_mapping(cls, data: Mapping) -> "BackendRun":
        names = {f.name for f in fields(cls)} - {"extra"}
        known = {k: v for k, v in data.items() if k in names}
        missing = {"t", "y", "yp", "steps", "success", "message"} - set(known)
        if missing:
            raise TypeError(f"a backend result lacks {', '.join(sorted(missing))}")
        run = cls(**known, extra={k: v for k, v in data.items() if k not in names})
        run.t = np.asarray(run.t, dtype=float)
        run.y = np.atleast_2d(np.asarray(run.y, dtype=float))
        run.yp = np.atleast_2d(np.asarray(run.yp, dtype=float))
        run.success, run.interrupted = bool(run.success), bool(run.interrupted)
        run.steps, run.nfev, run.njev = int(run.steps), int(run.nfev or 0), int(run.njev or 0)
        return run

    def replace(self, **changes) -> "BackendRun":
        """A copy with `changes` (a name that is not a field goes to :attr:`extra`)."""
        names = {f.name for f in fields(self)} - {"extra"}
        extra = {**self.extra, **{k: v for k, v in changes.items() if k not in names}}
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if k in names}, extra=extra)

    def _as_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        out.update(self.extra)
        return out

    def __getitem__(self, key: str):
        return self._as_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._as_dict())

    def __len__(self) -> int:
        return len(self._as_dict())


@dataclass(frozen=True)
class Backend:
    """A named integrator and the options it honours."""

    name: str
    integrate: Callable
    honours: frozenset
    """Options whose values change what it does (the others it is given are ignored)."""
    fixed_step: bool
    doc: str = ""

    def __call__(self, mod, p, t_out, y0, yp0, options, **keywords) -> BackendRun:
        run = self.integrate(mod, p, t_out, y0, yp0, options, **keywords)
        if not isinstance(run, BackendRun):
            raise TypeError(f"backend `{self.name}` returned {type(run).__name__}, not a BackendRun")
        return run

    def ignored(self, given: Mapping[str, object]) -> list[str]:
        """The options in `given` (explicitly set, not None) this backend does not use."""
        return [k for k, v in given.items() if v is not None and k not in self.honours]


def ignored_option_message(backend: Backend, names: list[str]) -> str:
    why = ("a fixed-step method: its accuracy is set by `step`" if backend.fixed_step
           else "a variable-step method: its steps follow `rtol` and `atol`")
    return f"solver `{backend.name}` ignores {', '.join(f'`{n}`' for n in names)} ({why})"


def ignored_in_file(backend: Backend, written: Mapping[str, object], given: Mapping[str, object]) -> list[str]:
    """The accuracy settings a model (or scene) file writes (`written`, by name) that
    `backend` does not use, in the file's order: those a command-line value replaces
    (`given`, None where not given) are left out (the option itself is reported), and so
    are all of them when the file or the command line also sets what `backend` does use
    for its accuracy (`step`; `rtol`/`atol`) — the file then holds settings for both
    kinds of solver (`rtol` for `--solver ida` beside `solver: midpoint` and its `step`)."""
    own = ("step",) if backend.fixed_step else ("rtol", "atol")
    if any(name in written or given.get(name) is not None for name in own):
        return []
    return [name for name in written if name not in backend.honours and given.get(name) is None]


__all__ = ["Backend", "BackendRun", "IgnoredOptionWarning", "ignored_in_file", "ignored_option_message"]
