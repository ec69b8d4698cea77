"""The ``modelDescription.xml`` of an FMU (FMI 2.0, co-simulation).

Input: the :class:`~phc.export.fmu_c.FmuData` that ``fmu.c`` embeds and a few names.
Output: the XML text (:func:`model_description`): the variables in value-reference order
(the order of ``fmu.c``'s ``VARIABLES``), their units (each one named in
``UnitDefinitions``), the model structure (every output, and every output among the initial
unknowns), the default experiment (the model's time span and output interval).
"""

from __future__ import annotations

from typing import Optional
from xml.sax.saxutils import quoteattr

from phc import __version__
from phc.export.fmu_c import FmuData


def _attr(name: str, value) -> str:
    text = "".join(ch if ch.isprintable() else " " for ch in str(value))
    return f" {name}={quoteattr(text)}"


def _real(x: float) -> str:
    return repr(float(x))


def model_description(d: FmuData, *, identifier: str, description: str, stop_time: float,
                      output_interval: Optional[float]) -> str:
    """The XML text (see the module docstring)."""
    units = sorted({v.unit for v in d.variables if v.unit})
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             "<fmiModelDescription" + _attr("fmiVersion", "2.0") + _attr("modelName", d.model) + _attr("guid", d.guid)
             + _attr("description", description) + _attr("generationTool", f"phc {__version__}")
             + _attr("variableNamingConvention", "flat") + _attr("numberOfEventIndicators", 0) + ">",
             "  <CoSimulation" + _attr("modelIdentifier", identifier)
             + _attr("canHandleVariableCommunicationStepSize", "true") + _attr("canInterpolateInputs", "false")
             + _attr("maxOutputDerivativeOrder", 0) + _attr("canRunAsynchronuously", "false")
             + _attr("canBeInstantiatedOnlyOncePerProcess", "false") + _attr("canGetAndSetFMUstate", "false")
             + _attr("canSerializeFMUstate", "false") + _attr("providesDirectionalDerivative", "false") + ">",
             "    <SourceFiles>",
             '      <File name="model.c"/>',
             '      <File name="fmu.c"/>',
             "    </SourceFiles>",
             "  </CoSimulation>"]
    if units:
        lines.append("  <UnitDefinitions>")
        lines += [f"    <Unit{_attr('name', u)}/>" for u in units]
        lines.append("  </UnitDefinitions>")
    lines += ["  <LogCategories>",
              '    <Category name="logStatusError" description="why a call failed (always logged)"/>',
              '    <Category name="logStatusWarning" description="warnings"/>',
              "  </LogCategories>",
              "  <DefaultExperiment" + _attr("startTime", _real(d.t0)) + _attr("stopTime", _real(stop_time))
              + (_attr("stepSize", _real(output_interval)) if output_interval else "") + "/>",
              "  <ModelVariables>"]
    outputs = []
    for vr, v in enumerate(d.variables):
        if v.causality == "output":
            outputs.append(vr + 1)
        head = ("    <ScalarVariable" + _attr("name", v.name) + _attr("valueReference", vr)
                + (_attr("description", v.description) if v.description else "") + _attr("causality", v.causality)
                + _attr("variability", v.variability) + (_attr("initial", v.initial) if v.initial else "") + ">")
        real = ("      <Real" + (_attr("unit", v.unit) if v.unit else "")
                + (_attr("start", _real(v.start)) if v.start is not None else "") + "/>")
        lines += [head, real, "    </ScalarVariable>"]
    lines += ["  </ModelVariables>", "  <ModelStructure>"]
    if outputs:
        lines += ["    <Outputs>", *[f'      <Unknown index="{k}"/>' for k in outputs], "    </Outputs>",
                  "    <InitialUnknowns>", *[f'      <Unknown index="{k}"/>' for k in outputs],
                  "    </InitialUnknowns>"]
    lines += ["  </ModelStructure>", "</fmiModelDescription>", ""]
    return "\n".join(lines)


__all__ = ["model_description"]
