"""The back ends: lower the DAE to an IR, print a standalone module, load it.

Beside the printers and loaders (NumPy, C, numba): the compiled model
(:mod:`phc.codegen.compiled`), its frozen description (:mod:`phc.codegen.description`) and
the cached front end of ``phc simulate`` (:mod:`phc.codegen.fastpath`)."""
