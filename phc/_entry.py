"""The `phc` command's entry point (and `python -m phc`): the process is phc's own.

phc's dense matrices are small (initialization, certification) and its sparse ones are
factorized by single-threaded SuperLU: a multi-threaded BLAS only adds thread start-up and,
on a loaded machine, spin-waiting (measured: consistent initialization 10× slower, IDA runs
burning 2× the CPU). The command therefore asks for one BLAS/OpenMP thread unless the user
chose otherwise, before numpy loads. ``import phc`` in a user's process changes no
environment variable: a script sets them itself (docs/how-to/solvers.md).
"""

from __future__ import annotations

import os

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def main(argv=None) -> int:
    for var in THREAD_VARIABLES:
        os.environ.setdefault(var, "1")
    from phc.cli import main as cli_main

    return cli_main(argv)
