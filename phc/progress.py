"""A small progress bar on stderr for runs longer than a couple of seconds."""

from __future__ import annotations

import math
import sys
import time

from phc.inert import inert


class Progress:
    """Call with the current time; draws once the run has taken `delay` seconds."""

    def __init__(self, t0: float, t1: float, label: str = "simulate", delay: float = 2.0, stream=None,
                 enabled: bool = True):
        self.t0, self.t1, self.label = t0, t1, inert(label)  # the model's name (phc.inert)
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


class CountProgress:
    """A bar over a number of runs (``phc sweep``): done/total, failures, rate and ETA.
    A terminal gets a redrawn bar; a log one line every 10 s (and at the end)."""

    def __init__(self, total: int, label: str = "sweep", done: int = 0, stream=None, enabled: bool = True):
        self.total, self.done, self.failed, self.label = total, done, 0, inert(label)
        self.first = done  # finished before this run (--resume): not part of the rate
        self.start = time.monotonic()
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = getattr(self.stream, "isatty", lambda: False)()
        self._last = -math.inf
        self._drawn = False

    def advance(self, failed: bool = False) -> None:
        self.done += 1
        self.failed += bool(failed)
        self.draw()

    def rate(self) -> float:
        """Runs per second since the start (nan before the first)."""
        elapsed = time.monotonic() - self.start
        ran = self.done - self.first
        return ran / elapsed if ran and elapsed > 0 else math.nan

    def eta(self) -> float:
        rate = self.rate()
        return (self.total - self.done) / rate if rate > 0 else math.nan

    def text(self) -> str:
        width = 30
        frac = self.done / self.total if self.total else 1.0
        rate, eta = self.rate(), self.eta()
        speed = "" if math.isnan(rate) else (f"{60 * rate:.3g} runs/min" if rate < 1 else f"{rate:.3g} runs/s")
        return (f"{self.label} [{'#' * int(frac * width):<{width}}] {100 * frac:5.1f}%  {self.done}/{self.total} runs"
                + (f", {self.failed} failed" if self.failed else "")
                + f"  elapsed {time.monotonic() - self.start:.1f} s"
                + (f"  {speed}  eta {eta:.0f} s" if speed else ""))

    def draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < (0.25 if self.tty else 10.0) and self.done < self.total:
            return
        self._last = now
        self.stream.write("\r" + self.text().ljust(100) if self.tty else self.text() + "\n")
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn and self.tty:
            self.stream.write("\n")
            self.stream.flush()
