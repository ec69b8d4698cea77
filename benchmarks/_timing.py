"""Shared timing helper of the benchmark scripts."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeat: int = 7, number: int = 50) -> tuple[float, float, float]:
    """(min, median, max) seconds per call of `fn` over `repeat` batches of `number` calls."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t) / number)
    return min(times), float(np.median(times)), max(times)
