"""Lowering of each component ``type`` to variables, equations and ports.

``LOWERERS[type](builder, ctx, full_name, spec, path)`` adds the component's variables,
equations, Hamiltonian, dissipation and ports to the :class:`phc.elaborate.Builder`.
``LOWERERS`` is the ``lower`` field of the component registry (:mod:`phc.registry`; the
built-in entries are in :mod:`phc.library.builtin`), read when used.
"""

from __future__ import annotations

from phc.registry import FieldView

LOWERERS = FieldView("lower")

__all__ = ["LOWERERS"]
