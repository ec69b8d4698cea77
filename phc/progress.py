"""A small progress bar on stderr for runs longer than a couple of seconds."""

from __future__ import annotations

import sys
import time


class Progress:
    """Call with the current time; draws once the run has taken `delay` seconds."""

    def __init__(self, t0: float, t1: float, label: str = "simulate", delay: float = 2.0, stream=None,
                 enabled: bool = True):
        self.t0, self.t1, self.label = t0, t1, label
        self.start = time.monotonic()
        self.delay = delay
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self._last = 0.0
        self._drawn = False

    def __call__(self, t: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        elapsed = now - self.start
        tty = getattr(self.stream, "isatty", lambda: False)()
        # A terminal gets a redrawn bar; a log gets one line every 10 s.
        if elapsed < self.delay or now - self._last < (0.25 if tty else 10.0):
            return
        self._last = now
        frac = min(1.0, max(0.0, (t - self.t0) / (self.t1 - self.t0))) if self.t1 > self.t0 else 1.0
        width = 30
        bar = "#" * int(frac * width)
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        self.stream.write(f"{chr(13) if tty else ''}{self.label} [{bar:<{width}}] {100 * frac:5.1f}%  t = {t:.4g}  "
                          f"elapsed {elapsed:.1f} s  eta {eta:.1f} s {'' if tty else chr(10)}")
        self.stream.flush()
        self._drawn = True

    def restart(self) -> None:
        """Start timing now (after setup work such as initialization)."""
        self.start = time.monotonic()

    def close(self) -> None:
        if self._drawn and getattr(self.stream, "isatty", lambda: False)():
            self.stream.write("\n")
            self.stream.flush()
