"""The `phc` command's entry point (and `python -m phc`): the process is phc's own.

phc's dense matrices are small (initialization, certification) and its sparse ones are
factorized by single-threaded SuperLU: a multi-threaded BLAS only adds thread start-up and,
on a loaded machine, spin-waiting (measured: consistent initialization 10× slower, IDA runs
burning 2× the CPU). The command therefore asks for one BLAS/OpenMP thread unless the user
chose otherwise, before numpy loads. ``import phc`` in a user's process changes no
environment variable: a script sets them itself (docs/how-to/solvers.md).

Likewise the command, and only the command, tunes Python's cyclic garbage collector: a model
of many components builds hundreds of thousands of sympy objects that live until the end,
and with the default thresholds the collector walks them again and again (measured: 15 % of
``phc validate`` on a chain of 10⁴ components). The objects the imports made are frozen
(never scanned again), the youngest generation is collected every 50 000 allocations
instead of every 700, and the middle one after 100 collections of the youngest instead of
10 (each of its collections walks every object the model made so far: measured 1.3 of
the 12 CPU seconds of ``validate_file`` on that chain, 0.6 with 100); cycles are still
collected. When the command is done, everything left is frozen too: the interpreter's
collection at exit would walk the whole model once more only to free it as the process
ends (measured: 1.6 of the 13 CPU seconds of ``phc validate`` on that chain; the
handlers registered with :mod:`atexit` still run). For the same reason a pause of the
collector (:func:`phc.pipeline.collector_paused`: validate, compile, check) ends, in the
command, by freezing what the paused block left: the next collection of the youngest
generation would otherwise walk every object made during the pause (measured 1.4 CPU
seconds after validating that chain: 2.3 million objects).
"""

from __future__ import annotations

import gc
import os

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
GC_YOUNG = 50_000
"""Allocations between collections of the youngest generation in the command (Python: 700)."""
GC_MIDDLE = 100
"""Collections of the youngest generation between two of the middle one (Python: 10)."""
COMMAND = False
"""True once :func:`main` runs: the process is the `phc` command's (read by
:func:`phc.pipeline.collector_paused`, never set by ``import phc``)."""


def main(argv=None) -> int:
    global COMMAND
    COMMAND = True
    for var in THREAD_VARIABLES:
        os.environ.setdefault(var, "1")
    from phc.cli import main as cli_main

    gc.freeze()
    gc.set_threshold(GC_YOUNG, GC_MIDDLE, *gc.get_threshold()[2:])
    try:
        return cli_main(argv)
    finally:
        gc.freeze()  # no collection of the model at exit (see above)
