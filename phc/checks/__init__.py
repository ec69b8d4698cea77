"""Certificates of a model: what ``phc check`` runs.

Input: a model or scene file. Output: a :class:`ModelCertificate` — the structural
certificate of the assembled model (:mod:`phc.checks.certify`: each component a Dirac
structure, each coupling surjective, each component's rows against its description,
:mod:`phc.checks.rows`), the structural balance of the DAE, and the certificate of the
compiled equations (:mod:`phc.checks.compiled`: power balance and passivity at sampled
consistent states), and the rank drops of the position constraints along the motion
(:mod:`phc.checks.motion`). Compilation runs the last one with fewer samples on every compile.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Optional

from phc.diagnostics import DiagnosticList
from phc.inert import inert


@dataclass
class ModelCertificate:
    """What ``phc check`` concludes about one model."""

    model: str
    structure: object
    """:class:`phc.checks.certify.Certificate` (None when the model has errors)."""
    compiled: Optional[object]
    """:class:`phc.checks.compiled.CompiledCertificate`, or None when the structure failed."""
    diagnostics: DiagnosticList
    motion: Optional[object] = None
    """:class:`phc.checks.motion.MotionSurvey`: the rank drops of the position constraints on
    the configurations reachable from the initial one (None when the compiled equations were
    not certified)."""

    @property
    def certified(self) -> bool:
        return (self.structure is not None and self.structure.certified
                and (self.compiled is None or (self.compiled.certified and not self.compiled.skipped)))

    def to_dict(self) -> dict:
        if self.structure is None:
            return {"model": self.model, "certified": False, "diagnostics": self.diagnostics.to_json()}
        report = self.structure.to_dict()
        report["compiled"] = self.compiled.to_dict() if self.compiled is not None else None
        report["singular_configurations"] = self.motion.to_dict() if self.motion is not None else None
        report["certified"] = self.certified
        return report

    def render_text(self) -> str:
        if self.structure is None:
            return "\n".join(d.render() for d in self.diagnostics)
        text = self.structure.render_text()
        if self.compiled is not None:
            model = inert(self.structure.model)  # as the structure's text shows it
            text = text.replace(f"{model}: {'certified' if self.structure.certified else 'NOT certified'}",
                                f"{model}: {'certified' if self.certified else 'NOT certified'}", 1)
            text += f"\ncompiled equations\n  {inert(self.compiled.summary())}"
        if self.motion is not None:
            text += f"\nsingular configurations along the motion\n  {inert(self.motion.summary())}"
        return text


def certify_model(path: str | os.PathLike, samples: int = 2) -> ModelCertificate:
    """Certify a model or scene file thoroughly (what ``phc check`` prints): `samples`
    random states besides the initial one for the structure, two more for the compiled
    equations. A structurally unbalanced model is still certified: the coupling
    certificate says why."""
    from phc.pipeline import collector_paused

    with collector_paused():  # as compile_model (phc.pipeline.collector_paused)
        return _certify_model(path, samples)


def _certify_model(path, samples: int) -> ModelCertificate:
    """:func:`certify_model` with the garbage collector already paused."""
    from phc.analysis.matching import check_balance
    from phc.checks.certify import certify
    from phc.diagnostics import DiagnosticList
    from phc.pipeline import _compile_assembled, _elaborate_file

    dae, diags, _, scene = _elaborate_file(path)  # read and assembled once: certified, then compiled
    if dae is None:
        return ModelCertificate(str(path), None, None, diags)
    cert = certify(dae, n_random=samples)  # the sign hints (PHC-W230) are among `diags`
    balance = check_balance(dae)
    seen = set(cert.diagnostics)
    cert.diagnostics.extend(d for d in dict.fromkeys(list(diags) + balance) if d not in seen)
    compiled = motion = None
    if cert.certified and not any(d.severity == "error" for d in balance):
        from phc.checks.compiled import certify_compiled

        built = _compile_assembled(path, scene, dae, DiagnosticList(list(diags) + balance).sorted(), certify=False)
        compiled = certify_compiled(built, n_random=samples + 2)
        cert.diagnostics.extend(compiled.diagnostics)
        if compiled.certified and not compiled.skipped:
            from phc.checks.motion import survey

            # the singular sets the sampled states miss: traced along the constraints (bounded)
            motion = survey(built)
            cert.diagnostics.extend(motion.diagnostics)
    cert.diagnostics[:] = cert.diagnostics.sorted()
    return ModelCertificate(str(path), cert, compiled, cert.diagnostics, motion)


__all__ = ["ModelCertificate", "certify_model"]
