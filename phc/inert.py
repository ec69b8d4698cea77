"""Inert text: what phc prints of file names, model names and messages.

A file name, a model's text or a message read back from a results file may hold control
characters (ESC starts a terminal escape sequence, BEL rings, CR and LF start a new line)
or formatting characters (bidirectional overrides reorder what a reader sees), and a line
of a CI log that starts with ``::`` (after blanks) is a GitHub Actions workflow command
(``::error file=...::...``, ``::add-mask::...``), as is one holding ``##[`` (the older
form). :func:`inert` is the one escaping every text sink of phc uses (diagnostics in the
text and GitHub formats, status and error lines, the summaries of runs and sweeps):

* control and formatting characters become visible escapes, ``\\x1b``, ``\\x07``,
  ``\\x0a``, ``\\u202e`` (so the text stays one line);
* a leading ``::`` becomes ``\\x3a:`` and ``##[`` becomes ``##\\x5b``, so no line that
  starts with user text starts a workflow command.

:func:`printable` is the form of a message (a diagnostic's text, an error line): line
breaks as blanks, very long words shortened, then :func:`inert`. This module imports
nothing of phc's, so that the cached front end of the command line stays lean.

JSON and SARIF need none of this: ``json.dumps`` writes control characters as ``\\u001b``
escapes, and SARIF's URIs are percent-encoded. The GitHub format escapes ``%``, CR, LF
(and ``:`` and ``,`` in properties) on top, as GitHub documents (:mod:`phc.cli.report_formats`).
"""

from __future__ import annotations

import re

__all__ = ["inert", "printable"]

_INVISIBLE = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f\u061c\u200b-\u200f\u2028-\u202e\u2060-\u206f\ufeff]")
"""Control characters (C0 but the tab, DEL, C1) and formatting characters (zero-width,
bidirectional marks and overrides, line and paragraph separators, the BOM)."""
_OLD_COMMAND = "##["


def _escape(char: str) -> str:
    code = ord(char)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def inert(text: object) -> str:
    """`text` as one line of visible characters that no terminal or CI log acts on.

    >>> inert("a\\x1b[31mb\\n::error::x")
    'a\\\\x1b[31mb\\\\x0a::error::x'
    >>> inert("  ::error file=a::b")
    '  \\\\x3a:error file=a::b'
    """
    out = _INVISIBLE.sub(lambda m: _escape(m.group()), str(text))
    stripped = out.lstrip()
    if stripped.startswith("::"):
        out = out[: len(out) - len(stripped)] + "\\x3a" + stripped[1:]
    if _OLD_COMMAND in out:
        out = out.replace(_OLD_COMMAND, "##\\x5b")
    return out


_ONE_LINE = re.compile(r"\s*[\r\n]+\s*")
_LONG_QUOTED = re.compile(r"`([^`]{201,})`")
_LONG_WORD = re.compile(r"[^\s`]{201,}")


def _one_line(text: str) -> str:
    return _ONE_LINE.sub(" ", text).strip()


def _shorten(text: str) -> str:
    return f"{text[:120]}…{text[-40:]}"


def printable(text: object, quoted: bool = True) -> str:
    """One line of visible text: line breaks as blanks, text longer than 200 characters
    shortened (a word; with `quoted`, also a `quoted` span, its length said), then
    :func:`inert` (control and formatting characters escaped, no workflow command)."""
    text = _one_line(str(text))
    if quoted:
        text = _LONG_QUOTED.sub(lambda m: f"`{_shorten(m.group(1))}` ({len(m.group(1))} characters)", text)
    text = _LONG_WORD.sub(lambda m: _shorten(m.group()), text)
    return inert(text)
