"""Shared timing helper of the benchmark scripts."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeat: int = 7, number: int = 50, clock=time.perf_counter) -> tuple[float, float, float]:
    """(min, median, max) seconds per call of `fn` over `repeat` batches of `number` calls
    (wall clock; ``clock=time.process_time`` for this process's CPU time)."""
    times = []
    for _ in range(repeat):
        t = clock()
        for _ in range(number):
            fn()
        times.append((clock() - t) / number)
    return min(times), float(np.median(times)), max(times)
