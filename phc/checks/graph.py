"""The interconnection graph, as the checks use it: see :mod:`phc.ir.interconnect`, which
owns it (one builder for a model spec and for an assembled topology)."""

from __future__ import annotations

from phc.ir.interconnect import (build_interconnection_graph, component_graph, component_of, connected_to,
                              independent_parts, kinematic_loops, to_dot, traversal_order)

__all__ = ["build_interconnection_graph", "component_graph", "component_of", "connected_to",
           "independent_parts", "kinematic_loops", "to_dot", "traversal_order"]
