"""The one progress line (build, synth and fit): rate and ETA on stderr, redrawn in place on a terminal, a line
every few seconds elsewhere."""
from __future__ import annotations

import sys
import time

TTY_EVERY = 0.2  # s: the least time between redraws on a terminal


def clock(seconds: float) -> str:
    """Seconds as H:MM:SS."""
    seconds = max(0, int(seconds))
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class Progress:
    """Counts finished units of work (samples, frames, steps) and reports rate and ETA.

    `done` units were finished before (resumed shards or steps): they count towards the total, not the rate.
    """

    def __init__(self, total: int, unit: str = "samples", enabled: bool = True, every: float = 5.0,
                 done: int = 0) -> None:
        self.total, self.unit, self.enabled = total, unit, enabled
        self._tty = sys.stderr.isatty()
        self.every = TTY_EVERY if self._tty else every
        self.done = self._before = done
        self.start = self._last = time.perf_counter()
        self._open = False  # a line drawn in place and not yet ended

    def advance(self, count: int, note: str = "") -> None:
        """Record `count` more units and redraw when due."""
        self.update(self.done + count, note)

    def update(self, done: int, note: str = "", force: bool = False) -> None:
        """Record that `done` units are finished and redraw when due (always when `force` or at the end)."""
        now = time.perf_counter()
        self.done = done
        finished = done >= self.total
        if not self.enabled or not (force or finished or now - self._last >= self.every):
            return
        self._last = now
        if self._tty:
            sys.stderr.write("\r" + self.line(now, note) + "\x1b[K" + ("\n" if finished else ""))
            self._open = not finished
        else:
            sys.stderr.write(self.line(now, note) + "\n")
        sys.stderr.flush()

    def line(self, now: float, note: str = "") -> str:
        """'[####------] 40% 800/2000 samples 95.1/s ETA 0:00:12'."""
        elapsed = now - self.start
        rate = (self.done - self._before) / elapsed if elapsed > 0 else 0.0
        fraction = min(self.done / self.total, 1.0) if self.total else 1.0
        bar = "#" * int(20 * fraction) + "-" * (20 - int(20 * fraction))
        eta = clock((self.total - self.done) / rate) if rate > 0 else "?"
        return f"[{bar}] {fraction:4.0%} {self.done}/{self.total} {self.unit} {rate:.1f}/s ETA {eta} {note}".rstrip()

    def close(self) -> None:
        """End a line left drawn in place (work stopped before the total)."""
        if self._open:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self._open = False
