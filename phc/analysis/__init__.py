"""Structural analysis on integer incidence data (no sympy beyond building it)."""
