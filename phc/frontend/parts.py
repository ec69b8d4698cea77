"""Parts: model files that declare `kind: part`.

A part is a reusable piece of a model — a gear stage, a filter section, a suspension
strut — that other models nest (`type: model`, `file: ...`). It is not a complete model:
its exposed ports are its interface, terminated by whatever the model using it connects
to them. So ``phc validate`` checks a part as far as it can on its own (the schema,
names, expressions, nested files, its connections, no inner port left dangling, the
assembly of its components) but not the structural balance of its equations,
which depends on those terminations (a gear alone, with both shafts free, is
undetermined; between a motor and a load it is not). ``phc compile``, ``simulate``,
``linearize`` and ``graph`` refuse a part, and so does a scene: run a model that uses it.

A part exposes at least one port and has no ``simulation`` section (PHC-E217); a part
where a complete model is needed is PHC-E216.
"""

from __future__ import annotations

from phc.diagnostics import Diagnostic, DiagnosticList

__all__ = ["part_diagnostics"]


def part_diagnostics(ctx, allowed: bool) -> DiagnosticList:
    """The diagnostics of a top-level file that declares `kind: part` (`ctx`: its
    :class:`phc.frontend.elaborate.FileContext`): PHC-E216 when a complete model is needed (not
    `allowed`), else PHC-E217 for what a part may not have or must have."""
    smap, spec = ctx.smap, ctx.spec
    out = DiagnosticList()
    where = smap.locate(("kind",)) if smap.has(("kind",)) else smap.locate(())
    if not allowed:
        out.append(Diagnostic(
            "PHC-E216", f"`{ctx.file}` is a part (`kind: part`), not a complete model: its exposed ports "
            "are terminated by the model that uses it", span=where, path="kind",
            hint="run a model that nests it (`type: model`, `file: ...`); `phc validate` checks the part "
            "itself; or remove `kind: part` to make it a model"))
        return out
    if not spec.ports:
        out.append(Diagnostic(
            "PHC-E217", "a part exposes at least one port: its `ports:` are how a model connects to it",
            span=where, path="kind",
            hint="expose the ports a model should connect under `ports:` (`name: {port: component.port}`), "
            "or remove `kind: part` to make it a complete model"))
    if smap.has(("simulation",)):
        out.append(Diagnostic(
            "PHC-E217", "a part has no `simulation` section: it is simulated inside the model that uses it, "
            "and a nested file's `simulation` is not read", span=smap.locate_key(("simulation",)),
            path="simulation",
            hint="move the initial values and outputs into that model (names get the part's component name "
            "as prefix: `strut.spring.x`), or remove `kind: part`"))
    return out
