"""Diagnostics for CI: GitHub Actions annotations and SARIF 2.1.0 (code scanning).

``phc validate|check|compile --format github`` prints one workflow command per
diagnostic, ``::error file=F,line=L,col=C,title=CODE::message. hint: ...`` (``::warning``
and ``::notice`` for the other severities), which GitHub Actions shows as annotations on
the lines of the pull request. ``--format sarif`` prints one SARIF 2.1.0 log (OASIS
Static Analysis Results Interchange Format) that ``github/codeql-action/upload-sarif``
uploads to code scanning: one run of the tool ``phc``, one rule per diagnostic code, one
result per diagnostic with its file, line and column.

File names and messages are inert (:func:`phc.inert.inert`: control characters as
visible escapes such as ``\\x1b``), then escaped as GitHub documents for workflow
commands: ``%``, CR and LF in the message, and ``:`` and ``,`` too in properties.

File paths are written relative to the current directory when they lie under it (CI
runs from the repository root, and both formats resolve paths from there), with ``/``
as separator.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import quote
from typing import Iterable, Optional

from phc.diagnostics import ERROR_CODES, Diagnostic, _printable
from phc.inert import inert

__all__ = ["SARIF_SCHEMA", "SARIF_VERSION", "github_annotations", "relative_uri", "sarif_log"]

SARIF_VERSION = "2.1.0"
SARIF_SCHEMA = "https://json.schemastore.org/sarif-2.1.0.json"
_GITHUB_COMMAND = {"error": "error", "warning": "warning", "info": "notice"}
_SARIF_LEVEL = {"error": "error", "warning": "warning", "info": "note"}


def relative_uri(file: str) -> str:
    """`file` relative to the current directory when it lies under it, with ``/`` as
    separator (what both GitHub and SARIF viewers resolve from the repository root)."""
    path = Path(file)
    try:
        rel = path.resolve().relative_to(Path.cwd().resolve()) if path.is_absolute() else path
    except ValueError:  # outside the working tree: keep it as given
        rel = path
    text = rel.as_posix()
    return text[2:] if text.startswith("./") else text


def _message(d: Diagnostic) -> str:
    """The one-line text of a diagnostic without its location and code (both are fields)."""
    text = (f"{_printable(d.path)}: " if d.path else "") + _printable(d.message)
    if d.hint:
        text += ("" if text[-1:] in ".!?:;" else ".") + f" hint: {_printable(d.hint)}"
    return text


def _escape_data(text: str) -> str:
    """A workflow command's message, escaped as GitHub documents (``%``, CR, LF); the text
    is inert already (no ESC or other control character, :func:`phc.inert.inert`)."""
    return text.replace("%", "%25").replace("\r", "%0D").replace("\n", "%0A")


def _escape_property(text: str) -> str:
    """A workflow command's property, escaped as GitHub documents (``%``, CR, LF, ``:``
    and ``,``)."""
    return _escape_data(text).replace(":", "%3A").replace(",", "%2C")


def github_annotations(diags: Iterable[Diagnostic], default_file: Optional[str] = None) -> list[str]:
    """One GitHub Actions workflow command per diagnostic (``::error file=…,line=…,col=…,
    title=PHC-E…::message``); a diagnostic without a location names `default_file` (the
    file being checked) without a line."""
    lines = []
    for d in diags:
        props = []
        file = d.span.file if d.span is not None else default_file
        if file:
            props.append(f"file={inert(_escape_property(relative_uri(file)))}")
        if d.span is not None:
            props += [f"line={d.span.line}", f"col={d.span.col}"]
        props.append(f"title={_escape_property(d.code)}")
        lines.append(f"::{_GITHUB_COMMAND.get(d.severity, 'error')} {','.join(props)}::"
                     f"{_escape_data(_message(d))}")
    return lines


def _rule(code: str) -> dict:
    rule = {"id": code}
    text = ERROR_CODES.get(code) or _documented_codes().get(code)
    if text:
        rule["shortDescription"] = {"text": text}
    rule["help"] = {"text": f"phc's documentation, Reference > Diagnostics, section {code}: an example and "
                            "the fix (docs/reference/diagnostics.md in phc's sources)"}
    return rule


def _documented_codes() -> dict[str, str]:
    """Code -> the short problem text of the diagnostics reference's table, when the
    documentation is next to the package (a source checkout); else empty."""
    page = Path(__file__).resolve().parents[2] / "docs" / "reference" / "diagnostics.md"
    try:
        text = page.read_text(encoding="utf-8")
    except OSError:
        return {}
    out = {}
    for line in text.splitlines():
        if line.startswith("| [PHC-"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if len(cells) >= 2:
                out[cells[0][1:cells[0].index("]")]] = cells[1]
    return out


def _sarif_uri(file: str) -> str:
    """A URI reference: relative (to %SRCROOT%, the current directory) and percent-encoded,
    or an absolute ``file://`` URI for a file outside the current directory."""
    rel = relative_uri(file)
    if Path(rel).is_absolute():
        return Path(rel).as_uri()
    return quote(rel, safe="/")


def _artifact_location(uri: str) -> dict:
    return {"uri": uri} if uri.startswith("file:") else {"uri": uri, "uriBaseId": "%SRCROOT%"}


def sarif_log(files: dict[str, list[Diagnostic]], version: str, command: str) -> dict:
    """A SARIF 2.1.0 log of one run of phc over `files` (file -> its diagnostics).

    Every result has a physical location: a diagnostic without a span points at the
    first line of the file it came from (code scanning drops results without one)."""
    results, rules, index = [], [], {}
    artifacts, artifact_index = [], {}

    def artifact(uri: str) -> int:
        if uri not in artifact_index:
            artifact_index[uri] = len(artifacts)
            artifacts.append({"location": _artifact_location(uri)})
        return artifact_index[uri]

    for file, diags in files.items():
        artifact(_sarif_uri(file))
        for d in diags:
            if d.code not in index:
                index[d.code] = len(rules)
                rules.append(_rule(d.code))
            span_file = d.span.file if d.span is not None else file
            uri = _sarif_uri(span_file)
            region = ({"startLine": max(1, d.span.line), "startColumn": max(1, d.span.col)}
                      if d.span is not None else {"startLine": 1})
            results.append({
                "ruleId": d.code,
                "ruleIndex": index[d.code],
                "level": _SARIF_LEVEL.get(d.severity, "error"),
                "message": {"text": _message(d)},
                "locations": [{"physicalLocation": {
                    "artifactLocation": {**_artifact_location(uri), "index": artifact(uri)},
                    "region": region}}],
            })
    root = Path.cwd().resolve().as_uri() + "/"
    return {
        "$schema": SARIF_SCHEMA,
        "version": SARIF_VERSION,
        "runs": [{
            "tool": {"driver": {"name": "phc", "version": version, "rules": rules}},
            "automationDetails": {"id": f"phc/{command}/"},
            "originalUriBaseIds": {"%SRCROOT%": {"uri": root}},
            "artifacts": artifacts,
            "columnKind": "unicodeCodePoints",
            "results": results,
        }],
    }
