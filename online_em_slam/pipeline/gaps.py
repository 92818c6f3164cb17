"""Loss detection in data time: a periodic stream with a hole lost messages.

Message queues (a full KEEP_LAST history, a best-effort link) lose messages
without telling the subscriber.  Odometry and control are periodic, so a gap
much longer than the stream's usual period means messages were lost upstream;
they are counted as ``<kind>_lost`` (the estimated number of missing messages).
The usual period is the median of the recent steps, so a slow start or jitter
does not count as loss.
"""
from __future__ import annotations

from collections import Counter, deque

import numpy as np

from .inputs import KIND_NAME

HISTORY = 64            # recent steps kept for the period estimate
MIN_STEPS = 8           # steps seen before gaps are judged
GAP_FACTOR = 1.8        # a step longer than this many periods is a gap
REESTIMATE = 16         # the period is re-estimated every this many steps (a median per message is costly)


class GapDetector:
    def __init__(self, kinds: tuple[int, ...], drops: Counter | None = None) -> None:
        self.kinds = tuple(kinds)
        self.drops = drops if drops is not None else Counter()
        self.reset()

    def reset(self) -> None:
        self._last: dict[int, float] = {}
        self._steps: dict[int, deque] = {k: deque(maxlen=HISTORY) for k in self.kinds}
        self._period: dict[int, float | None] = {k: None for k in self.kinds}
        self._since: dict[int, int] = {k: 0 for k in self.kinds}
        self._refused: dict[int, int] = {k: 0 for k in self.kinds}

    def arrived_unusable(self, kind: int) -> None:
        """A message of ``kind`` came but its stamp cannot be placed (an outlier): not lost."""
        if kind in self._refused:
            self._refused[kind] += 1

    def period(self, kind: int) -> float | None:
        return self._period.get(kind)

    def _note_step(self, kind: int, step: float) -> None:
        steps = self._steps[kind]
        steps.append(step)
        self._since[kind] += 1
        if len(steps) >= MIN_STEPS and (self._period[kind] is None or self._since[kind] >= REESTIMATE):
            self._period[kind] = float(np.median(steps))
            self._since[kind] = 0

    def observe(self, kind: int, stamp: float) -> int:
        """Note an in-order input; returns the number of messages judged lost just before it."""
        if kind not in self._steps:
            return 0
        last = self._last.get(kind)
        self._last[kind] = stamp
        if last is None or stamp <= last:
            return 0
        refused, self._refused[kind] = self._refused[kind], 0
        step = stamp - last
        period = self.period(kind)
        self._note_step(kind, step)
        if period is None or period <= 0 or step <= GAP_FACTOR * period:
            return 0
        lost = int(round(step / period)) - 1 - refused
        if lost > 0:
            self.drops[f"{KIND_NAME[kind]}_lost"] += lost
        return max(lost, 0)
