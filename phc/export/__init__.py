"""Exported artefacts of a compiled model: an FMI 2.0 co-simulation FMU (:mod:`phc.export.fmu`).

``phc export MODEL_OR_SCENE.yaml --fmu OUT.fmu`` (docs/how-to/other-tools.md).
"""

from phc.export.fmu import ExportError, FmuReport, export_fmu

__all__ = ["ExportError", "FmuReport", "export_fmu"]
