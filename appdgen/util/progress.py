"""A progress line with rate and ETA on stderr: redrawn in place on a terminal, a line every few seconds elsewhere."""
from __future__ import annotations

import sys
import time


def _clock(seconds: float) -> str:
    """Seconds as H:MM:SS."""
    seconds = max(0, int(seconds))
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class Progress:
    """Counts finished units of work (samples) and reports rate and ETA."""

    def __init__(self, total: int, unit: str = "samples", enabled: bool = True, every: float = 5.0) -> None:
        self.total, self.unit, self.enabled, self.every = total, unit, enabled, every
        self.done = 0
        self.start = self._last = time.perf_counter()
        self._tty = sys.stderr.isatty()

    def advance(self, count: int, note: str = "") -> None:
        """Record `count` more units and redraw when due."""
        self.done += count
        now = time.perf_counter()
        if self.enabled and (self._tty or now - self._last >= self.every or self.done >= self.total):
            self._last = now
            end = "\r" if self._tty and self.done < self.total else "\n"
            sys.stderr.write(self.line(now, note) + end)
            sys.stderr.flush()

    def line(self, now: float, note: str = "") -> str:
        """'[####------] 40% 800/2000 samples 95.1/s ETA 0:00:12'."""
        elapsed = now - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        fraction = self.done / self.total if self.total else 1.0
        bar = "#" * int(20 * fraction) + "-" * (20 - int(20 * fraction))
        eta = _clock((self.total - self.done) / rate) if rate > 0 else "?"
        return f"[{bar}] {fraction:4.0%} {self.done}/{self.total} {self.unit} {rate:.1f}/s ETA {eta} {note}".rstrip()
