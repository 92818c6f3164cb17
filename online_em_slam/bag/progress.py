"""A plain-text progress bar on stderr for the command-line tools (convert, run)."""
from __future__ import annotations

import sys
import time


class Progress:
    """Plain-text progress bar on a stream (stderr), redrawn at most every 0.2 s."""

    def __init__(self, total: int, label: str = "", stream=None, enabled: bool = True, width: int = 30):
        self.total, self.label, self.width = max(int(total), 1), label, width
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.start = self._last = time.monotonic()
        self.count = 0
        self._drawn = -1

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if self.enabled and (now - self._last >= 0.2 or self.count >= self.total):
            self._last = now
            self._draw(now)

    def _draw(self, now: float) -> None:
        frac = min(self.count / self.total, 1.0)
        bar = "#" * int(frac * self.width)
        self._drawn = self.count
        self.stream.write(f"\r{self.label} [{bar:<{self.width}}] {100 * frac:5.1f}% "
                          f"{self.count}/{self.total} {now - self.start:6.1f}s")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            if self._drawn != self.count:
                self._draw(time.monotonic())
            self.stream.write("\n")
            self.stream.flush()
