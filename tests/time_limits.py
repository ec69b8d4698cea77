"""A time limit for a test's input: CPU time first, wall-clock time as a backstop.

A hang (an endless loop) is a failure, not a stuck CI job; but a loaded machine stretches
wall-clock time, not the work an input costs, so the limit that decides is CPU time.
"""

from __future__ import annotations

import contextlib
import signal

WALL_FACTOR = 20
"""A limit in wall-clock time as well, this many times the CPU limit: an input that blocks
(a FIFO opened for reading) uses no CPU. Limits are CPU time first because a loaded machine
stretches wall time (the first input also imports networkx' flow algorithms: 5 s of wall
time at a load of 6 on 2 cores), not the work an input costs."""

SUBPROCESS_TIMEOUT = 600
"""Seconds a test waits for a phc subprocess: a guard against a hang, not a measure of
speed (a compile of every shipped model took over 120 s at a load of 7 on 2 cores)."""


class Hang(BaseException):
    """An input ran past its time limit (a BaseException: phc's own `except Exception` must
    not swallow it)."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`Hang` in the test process when the block uses more than `seconds` of
    CPU time, or more than :data:`WALL_FACTOR` times that of wall-clock time."""
    def expired(signum, frame):
        what = "CPU" if signum == signal.SIGPROF else "wall-clock"
        raise Hang(f"no result after {seconds * (1 if signum == signal.SIGPROF else WALL_FACTOR)} s of {what} time")

    previous = {sig: signal.signal(sig, expired) for sig in (signal.SIGALRM, signal.SIGPROF)}
    signal.setitimer(signal.ITIMER_PROF, seconds)
    signal.setitimer(signal.ITIMER_REAL, seconds * WALL_FACTOR)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.setitimer(signal.ITIMER_PROF, 0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
