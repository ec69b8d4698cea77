"""Code generation: lower the DAE to an IR, print a standalone module, load it."""
