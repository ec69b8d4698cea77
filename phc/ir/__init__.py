"""The intermediate representation: the interconnected model and its flat DAE.

Stages "interconnect" and "assemble" of the pipeline (docs/theory/pipeline.md):

* :mod:`phc.ir.interconnect` — the one interconnection graph (networkx) of components,
  ports and connections: port compatibility, scene pruning, the certificate's coupling;
* :mod:`phc.ir.wires` — connections that keep the sign of a series chain as drawn;
* :mod:`phc.ir.assemble` — lowered, interconnected components into one :class:`~phc.ir.dae.Dae`;
* :mod:`phc.ir.dae` — the flat relation system ``F(t, y, ẏ, p) = 0`` every model becomes;
* :mod:`phc.ir.initial_fields` — initial fields of distributed components, independent of
  the mesh.

Structural analysis of the DAE is :mod:`phc.analysis`; the back ends that print it are
:mod:`phc.codegen`. Nothing is imported here: each module is imported where it is used.
"""
