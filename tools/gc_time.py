"""CPU seconds a `phc` command spends in Python's cyclic garbage collector.

Runs the command in this process through its entry point (:func:`phc._entry.main`, with
its collector settings) and times every collection with :data:`gc.callbacks`; prints the
command's CPU seconds and the part of them spent collecting, on standard error. The share
of the collector is steadier than the total on a shared machine, whose load moves CPU times
by tens of percent.

Run: ``PHC_CACHE_DIR=$(mktemp -d) python tools/gc_time.py validate model.yaml`` (a fresh
cache directory: a stored result of an unchanged file would skip the work).
"""

from __future__ import annotations

import gc
import sys
import time


def main(argv: list[str]) -> int:
    spent, started, count = [0.0], [0.0], [0]

    def timer(phase, info):
        if phase == "start":
            started[0] = time.process_time()
        else:
            spent[0] += time.process_time() - started[0]
            count[0] += 1

    gc.callbacks.append(timer)
    from phc._entry import main as phc_main

    t = time.process_time()
    try:
        return phc_main(argv)
    finally:
        print(f"total {time.process_time() - t:.2f} s CPU, in gc {spent[0]:.2f} s ({count[0]} collections)",
              file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
