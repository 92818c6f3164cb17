"""Stamp-ordered merge of the input streams by per-stream watermark.

Every stream arrives in stamp order, so an input may be released once every
stream still alive has delivered something at least as recent: the merge then
equals a global sort by (stamp, tie rule, arrival) however the streams interleave
on the wire, which is what lets the node and the offline runner feed the
estimator the identical sequence.  Every message of a stream refreshes its
liveness and advances its watermark, including empty clouds and messages that
are dropped later, so a stream that reports "nothing seen" never holds the
others back.  A stream silent for ``silence`` wall seconds stops holding the
others back; they then run ``SILENT_LAG_FACTOR * lag`` stamp seconds behind the
newest input, where ``lag`` is how far behind the others that stream used to
arrive, so a lagging detector that resumes after a silence is not dropped as
late.  The remembered lag is a sample, not a bound: the executor's order and a
loaded machine add about as much again (a 60 ms detector was seen arriving
100 ms behind the odometry), hence the factor.
"""
from __future__ import annotations

import heapq
import math
from collections import Counter, deque

from .inputs import MOTION_KINDS, Input

LAG_MEMORY = 32          # arrivals over which a stream's lag behind the others is remembered
SILENT_LAG_FACTOR = 2.0  # a silent stream is waited for twice its largest remembered lag


class Sequencer:
    def __init__(self, streams: tuple[int, ...], silence: float, drops: Counter | None = None) -> None:
        self.streams = tuple(streams)
        self.silence = float(silence)        # <= 0: no reordering, release on arrival
        self.drops = drops if drops is not None else Counter()
        self.reset()

    def reset(self) -> None:
        self._heap: list[Input] = []
        self._seq = 0
        self._newest: dict[int, float] = {}         # per stream, every message heard (watermark)
        self._queued: dict[int, float] = {}         # per stream, the last input queued (order check)
        self._heard: dict[int, float] = {}          # wall time each stream was last heard
        self._lags: dict[int, deque] = {k: deque(maxlen=LAG_MEMORY) for k in self.streams}
        self._first_wall: float | None = None
        self.released: float | None = None          # stamp of the last released input

    # ------------------------------------------------------------------ state
    def __len__(self) -> int:
        return len(self._heap)

    @property
    def newest(self) -> float | None:
        return max(self._newest.values()) if self._newest else None

    def newest_of(self, kind: int) -> float | None:
        return self._newest.get(kind)

    # ------------------------------------------------------------------ input
    def heard(self, kind: int, stamp: float, wall: float) -> None:
        """A message of ``kind`` stamped ``stamp`` arrived (used or not): the stream is alive up to it."""
        if self._first_wall is None:
            self._first_wall = wall
        self._heard[kind] = wall
        previous = self._newest.get(kind)
        others = [v for k, v in self._newest.items() if k != kind]
        if others and (previous is None or stamp > previous):
            self._lags.setdefault(kind, deque(maxlen=LAG_MEMORY)).append(max(max(others) - stamp, 0.0))
        self._newest[kind] = stamp if previous is None else max(previous, stamp)

    def push(self, item: Input, wall: float) -> list[Input]:
        """Queue ``item`` (counted and refused when it cannot be released in order); release what is safe."""
        self.heard(item.kind, item.stamp, wall)
        previous = self._queued.get(item.kind)
        if previous is not None and item.stamp <= previous:
            self.drops["out_of_order" if item.stamp < previous else self._repeat_reason(item.kind)] += 1
            return self.release(wall)
        self._queued[item.kind] = item.stamp
        if self.released is not None and item.stamp < self.released:
            self.drops["out_of_order"] += 1       # later than a stream that was no longer waited for
            return self.release(wall)
        self._seq += 1
        item.seq = self._seq
        item.wall = wall
        heapq.heappush(self._heap, item)
        return self.release(wall)

    @staticmethod
    def _repeat_reason(kind: int) -> str:
        return "zero_time_step" if kind in MOTION_KINDS else "repeated_stamp"

    # ------------------------------------------------------------------ output
    def watermark(self, wall: float) -> float:
        """Stamp up to which every input is known to have arrived."""
        if self.silence <= 0 or self._first_wall is None:
            return math.inf                      # no reordering, or nothing heard yet
        marks, silent = [], []
        for kind in self.streams:
            heard = self._heard.get(kind)
            if heard is None:
                if wall - self._first_wall < self.silence:
                    marks.append(-math.inf)      # not heard yet: wait for it a while after start-up
            elif wall - heard < self.silence:
                marks.append(self._newest[kind])
            else:
                silent.append(kind)
        if not marks:
            return math.inf                      # every stream stopped: nothing left to wait for
        if silent:
            newest = max(self._newest.values())
            marks += [newest - SILENT_LAG_FACTOR * max(self._lags[k], default=0.0) for k in silent]
        return min(marks)

    def release(self, wall: float, limit: float | None = None) -> list[Input]:
        """Inputs at or below the watermark (or ``limit``), in (stamp, tie rule, arrival) order."""
        mark = self.watermark(wall) if limit is None else limit
        out = []
        while self._heap and self._heap[0].stamp <= mark:
            out.append(heapq.heappop(self._heap))
        if out:
            self.released = out[-1].stamp if self.released is None else max(self.released, out[-1].stamp)
        return out

    def flush(self) -> list[Input]:
        """Everything still queued (end of a bag, or every stream stopped)."""
        return self.release(0.0, math.inf)
