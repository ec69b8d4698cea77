"""Lowering of each component ``type`` to variables, equations and ports.

``LOWERERS[type](b, ctx, full_name, spec, path)`` writes the component's variables,
equations, Hamiltonian, dissipation and ports into `b`, a :class:`phc.frontend.lowering.Recorder`
of this component only, and reads the rest of the model through its read-only
``b.context``; :func:`phc.frontend.lowering.lower` runs it and returns the frozen
:class:`phc.frontend.lowering.ComponentLowering` the elaborate pass folds into the model.
``LOWERERS`` is the ``lower`` field of the component registry (:mod:`phc.library.registry`; the
built-in entries are in :mod:`phc.library.builtin`), read when used.
"""

from __future__ import annotations

from phc.library.registry import FieldView

LOWERERS = FieldView("lower")

__all__ = ["LOWERERS"]
