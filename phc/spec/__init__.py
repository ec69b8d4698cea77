"""The input layer: pydantic models of what a user writes (`*Spec`)."""

from phc.spec.model import FORMAT_VERSION, ModelSpec

__all__ = ["FORMAT_VERSION", "ModelSpec"]
