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

import math
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


class ArrivalLag:
    """How far behind its inputs the node is: the wall time from a message's publication
    (its source timestamp, from the middleware) to its callback, less the smallest such
    delay seen (the link's own, and any offset between the two machines' clocks).

    Past ``limit`` seconds (half the merge's ``input_delay``, input_pipeline.BEHIND_SHARE) the
    messages wait in the node's own queues: the node is behind.
    A stream then looks silent only because its callbacks wait behind the others', so
    the merge must keep waiting for it (or its motion would come out of order), and
    observation updates are shed until the node has caught up.
    """

    def __init__(self, limit: float = 0.5) -> None:
        self.limit = float(limit)
        self.reset()

    def reset(self) -> None:
        self.baseline = math.inf
        self.excess = 0.0
        self.max_excess = 0.0
        self.noted: float | None = None          # monotonic time of the last note

    def note(self, delay: float, now: float) -> None:
        """The publication-to-callback delay (s) of one message, noted at ``now`` (monotonic s)."""
        if not math.isfinite(delay):
            return
        self.baseline = min(self.baseline, delay)
        self.excess = delay - self.baseline
        self.max_excess = max(self.max_excess, self.excess)
        self.noted = now

    def behind(self, now: float) -> bool:
        """Messages arrive late, and still arrive: once nothing has come for ``limit`` seconds
        the node's queues are empty, whatever the last message's delay was."""
        return self.excess > self.limit and self.noted is not None and now - self.noted <= self.limit
