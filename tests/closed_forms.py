"""Closed-form solutions the tests compare phc's runs with."""

from __future__ import annotations

import math


def msd_x(k: float, t: float, m: float = 1.0, c: float = 0.4, x0: float = 0.5) -> float:
    """Closed form of the free damped oscillator m x'' + c x' + k x = 0, x(0) = x0, x'(0) = 0
    (underdamped)."""
    w0 = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1 - zeta ** 2)
    return math.exp(-zeta * w0 * t) * (x0 * math.cos(wd * t) + zeta * w0 * x0 / wd * math.sin(wd * t))
