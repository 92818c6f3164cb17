"""Graceful degradation: shed observation updates, never motion, when the node cannot keep up.

The node's share of wall time spent on inputs over the last ``window`` seconds
is its load.  Above ``limit`` the input queues fill faster than they drain and
will overflow; observation updates are the expensive part (a filter step and an
EM update each) while a motion input costs microseconds, so the node then
skips observation updates (counted as ``overload``) until the load falls below
``limit`` again.  Motion is always integrated: the pose stays right and the map
only misses some scans.
"""
from __future__ import annotations

from collections import deque


class LoadMonitor:
    def __init__(self, window: float = 1.0, limit: float = 0.9) -> None:
        self.window = float(window)
        self.limit = float(limit)     # > 1 disables shedding
        self._spans: deque = deque()  # (end wall time, busy seconds)
        self._busy = 0.0

    def add(self, end: float, busy: float) -> None:
        """``busy`` seconds of input processing that ended at wall time ``end``."""
        self._spans.append((end, busy))
        self._busy += busy
        self._forget(end)

    def _forget(self, now: float) -> None:
        while self._spans and self._spans[0][0] < now - self.window:
            self._busy -= self._spans.popleft()[1]

    def load(self, now: float) -> float:
        self._forget(now)
        return max(self._busy, 0.0) / self.window

    def overloaded(self, now: float) -> bool:
        return self.load(now) > self.limit
