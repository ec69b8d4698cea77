"""Reading one model file into a validated :class:`~phc.spec.ModelSpec`, nothing more.

The first step of the elaborate pass (:mod:`phc.frontend.elaborate`), and what ``phc.load_model``
offers on its own: YAML with positions (:mod:`phc.frontend.source`), then pydantic validation,
every problem a located :class:`~phc.diagnostics.Diagnostic`.
"""

from __future__ import annotations

import os
from typing import Optional

import pydantic

from phc.diagnostics import Diagnostic, DiagnosticList, allowed_keys_from_model, from_pydantic
from phc.frontend.source import SourceMap, SourceSpan, _read_parsed, load_yaml
from phc.spec import ModelSpec

__all__ = ["load_spec", "load_spec_bytes"]

_ALLOWED_KEYS = allowed_keys_from_model(ModelSpec)


def load_spec(path: str | os.PathLike) -> tuple[Optional[ModelSpec], Optional[SourceMap], DiagnosticList]:
    """Read and validate one model file (no elaboration).

    Returns
    -------
    spec, smap, diagnostics
        `spec` is None when the file has errors.
    """
    # the parsed data as the file's other reads share it, not a copy: validation only reads it
    # (pydantic builds the spec's own dicts and lists), and nothing else is kept of it
    data, smap, problems = _read_parsed(path)
    return _spec_from_yaml(path, data, smap, problems)


def load_spec_bytes(raw: bytes, path: str | os.PathLike) -> tuple[Optional[ModelSpec], Optional[SourceMap],
                                                                  DiagnosticList]:
    """:func:`load_spec` of a file's content already read (`path` names it in diagnostics)."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        return None, None, DiagnosticList([Diagnostic(
            "PHC-E004", f"the file is not valid UTF-8 (byte {raw[err.start]:#04x} on line {line})",
            span=SourceSpan(str(path), 1, 1), hint="save the file with UTF-8 encoding")])
    data, smap, problems = load_yaml(text, str(path))
    return _spec_from_yaml(path, data, smap, problems)


def _spec_from_yaml(path, data, smap, problems) -> tuple[Optional[ModelSpec], Optional[SourceMap], DiagnosticList]:
    diags = DiagnosticList()
    diags.extend(problems)
    if diags.has_errors or smap is None:
        return None, smap, diags
    if data is None:
        diags.append(Diagnostic("PHC-E005", "the model file is empty; it needs at least `components`",
                                span=SourceSpan(str(path), 1, 1)))
        return None, smap, diags
    if not isinstance(data, dict):
        diags.append(Diagnostic("PHC-E013", "a model file must be a mapping with `components`, "
                                "`connections`, ...", span=smap.locate(())))
        return None, smap, diags
    try:
        spec = ModelSpec.model_validate(data)
    except pydantic.ValidationError as err:
        diags.extend(from_pydantic(err, smap, allowed_keys=_ALLOWED_KEYS))
        return None, smap, diags
    return spec, smap, diags
