"""The front end: model files to one description per component.

Stages "load" and "elaborate" of the pipeline (docs/theory/pipeline.md):

* reading files safely: :mod:`phc.frontend.files` (paths inside the model's tree),
  :mod:`phc.frontend.source` and :mod:`phc.frontend.source_map` (YAML through a safe composer,
  every node with its file, line and column), :mod:`phc.frontend.parts` (``kind: part``);
* what a run changes before elaboration: :mod:`phc.frontend.scene`, :mod:`phc.frontend.effects`,
  :mod:`phc.frontend.reference_values`;
* the values a model gives: :mod:`phc.frontend.units` and :mod:`phc.frontend.unit_scales`
  (units and their scales), :mod:`phc.frontend.inputs` (input signals),
  :mod:`phc.frontend.budget` (the cost of a model, refused above a budget before the work),
  :mod:`phc.frontend.state_hints` (what to say of a misspelt state);
* elaboration: :mod:`phc.frontend.elaborate` (model files to an ``Elaboration``),
  :mod:`phc.frontend.lowering` (one component, a pure function of its spec) and
  :mod:`phc.frontend.reporter` (located diagnostics and expression parsing every pass uses).

The model language itself is :mod:`phc.spec`, the component types :mod:`phc.library`
(with the registry, :mod:`phc.library.registry`), the discretization of distributed
components :mod:`phc.discretize`. Nothing is imported here: each module is imported where
it is used.
"""
