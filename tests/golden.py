"""Expected diagnostic lines that hold values of phc's own random samples.

Some checks evaluate a model at sampled states and print what they found there: the power
``f·e`` of a non-passive resistive law at a random flow, ``max |J + Jᵀ|`` of a modulated
``J`` at random states, the mismatch of a rigid port's ``position`` at random ``q``. Those
numbers depend on the sampler and its seed, not on the mistake; an expected line holds a
placeholder in their place:

    <sampled>     any number as phc prints it (``0.251``, ``-1.2e-05``)
    <sampled+>    a number > 0   (a maximum of a nonzero deviation)
    <sampled->    a number < 0   (the power a non-passive law supplies)

Everything else in the line is compared to the letter. :func:`resolved` swaps each expected
line that matches for the line phc printed, so a test writes ``assert got ==
resolved(expected, got)`` and pytest shows a plain diff of what really differs.
:func:`shift_seeds` makes every seeded sampler of phc draw other samples, to show that a
corpus does not pin them.
"""

from __future__ import annotations

import re

import numpy as np

_POSITIVE = r"(?=0*\.?0*[1-9])\d*\.?\d+(?:e[+-]?\d+)?"
PLACEHOLDERS = {"<sampled>": r"-?\d*\.?\d+(?:e[+-]?\d+)?", "<sampled+>": _POSITIVE, "<sampled->": "-" + _POSITIVE}
_TOKEN = re.compile("|".join(re.escape(p) for p in PLACEHOLDERS))


def has_placeholders(lines) -> bool:
    return any(_TOKEN.search(line) for line in lines)


def pattern(expected: str) -> re.Pattern:
    """The expected line as a regular expression: literal but for its placeholders."""
    parts, pos = [], 0
    for m in _TOKEN.finditer(expected):
        parts += [re.escape(expected[pos:m.start()]), f"(?:{PLACEHOLDERS[m.group()]})"]
        pos = m.end()
    parts.append(re.escape(expected[pos:]))
    return re.compile("".join(parts))


def matches(expected: str, line: str) -> bool:
    return pattern(expected).fullmatch(line) is not None


def resolved(expected: list[str], got: list[str]) -> list[str]:
    """`expected`, with each line that matches the line of `got` at its place replaced by it."""
    return [got[i] if i < len(got) and matches(line, got[i]) else line for i, line in enumerate(expected)]


def shift_seeds(monkeypatch, by: int) -> None:
    """Make ``np.random.default_rng(seed)`` — every sampler of phc — draw from ``seed + by``."""
    original = np.random.default_rng

    def shifted(seed=None, *args, **kwargs):
        return original(seed if seed is None else np.asarray(seed) + by, *args, **kwargs)

    monkeypatch.setattr(np.random, "default_rng", shifted)
