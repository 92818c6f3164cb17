"""How far the estimator runs behind its inputs, in stamp seconds, without the middleware's help.

The age of an input is ``reference - stamp``: with a clock (the node's ROS clock, which
under ``use_sim_time`` follows the replay's /clock, so the age is in the same seconds as the
stamps) the reference is the clock's time; without one (offline, or a test) it is the
newest stamp heard on any stream, which sees only what waits in the pipeline's own queue.
Each stream has an age it always has: a link's latency, a detector's processing time, a
sensor whose stamps are offset by a constant.  That is the smallest age seen at arrival,
the stream's *baseline*, and only the age beyond it counts:

* *lateness*: the age beyond the baseline with which an input arrives; the node's own
  queues (the middleware's, the executor's) hold its messages while it is positive.  While
  some stream that still delivers arrives later than ``behind_after``, the node is *behind*:
  a stream that seems silent may be waiting in those queues (:attr:`Sequencer.consumer_behind`).
* *lag* of an input being applied: its age then, beyond the baseline.  Observation updates
  more than ``shed_after`` behind are shed (input_pipeline), so motion, always applied, stays
  within the bound as long as motion alone keeps up.

An input stamped more than ``ahead_tolerance`` ahead of the reference is not on the
reference's time line (before the first /clock, just after the clock jumped back, a coarse
/clock): it is not measured.  :meth:`reset` forgets the baselines (a time jump, a reset).
"""
from __future__ import annotations

import math
from typing import Callable, Optional

StampClock = Callable[[], Optional[float]]


class InputLag:
    def __init__(self, limit: float, clock: StampClock | None = None, ahead_tolerance: float = 1.0,
                 silence: float = 1.0) -> None:
        self.clock = clock                      # seconds on the stamps' time line, None/<= 0: unknown
        self.ahead_tolerance = float(ahead_tolerance)
        self.silence = float(silence)           # wall s: a stream quieter than this is not judged behind
        self.set_limit(limit)
        self.max_lag = 0.0                      # largest lag of an applied input (diagnostics)
        self.reset()

    def set_limit(self, limit: float) -> None:
        """``limit`` (s, stamp time; 0: off): observations are shed from half of it on, the node is
        behind from half of it on."""
        self.limit = max(float(limit), 0.0)
        self.shed_after = self.behind_after = 0.5 * self.limit if self.limit > 0 else math.inf

    def reset(self) -> None:
        self._baseline: dict[int, float] = {}
        self._late: dict[int, tuple[float, float]] = {}    # per stream: (lateness, wall time) of its last arrival
        self._newest = -math.inf
        self.lag = 0.0                                    # lag of the last applied input

    # ------------------------------------------------------------------ measuring
    def _reference(self) -> float | None:
        if self.clock is None:
            return self._newest if math.isfinite(self._newest) else None
        now = self.clock()
        return now if now is not None and now > 0.0 else None

    def _age(self, stamp: float) -> float | None:
        reference = self._reference()
        if reference is None or not math.isfinite(stamp) or stamp - reference > self.ahead_tolerance:
            return None
        return reference - stamp

    def arrived(self, kind: int, stamp: float, wall: float) -> None:
        """An input of stream ``kind`` stamped ``stamp`` reached the node at ``wall`` (monotonic s)."""
        if math.isfinite(stamp):
            self._newest = max(self._newest, stamp)
        age = self._age(stamp)
        if age is None:
            return
        baseline = min(self._baseline.get(kind, age), age)
        self._baseline[kind] = baseline
        self._late[kind] = (age - baseline, wall)

    def applied(self, kind: int, stamp: float) -> float:
        """The lag (s) of an input of ``kind`` stamped ``stamp`` applied now (0 when unknown)."""
        age = self._age(stamp)
        baseline = self._baseline.get(kind)
        self.lag = max(age - baseline, 0.0) if age is not None and baseline is not None else 0.0
        self.max_lag = max(self.max_lag, self.lag)
        return self.lag

    # ------------------------------------------------------------------ judging
    def lateness(self, wall: float) -> float:
        """The largest lateness of the last arrivals of the streams heard within ``silence``."""
        return max((late for late, heard in self._late.values() if wall - heard <= self.silence), default=0.0)

    def behind(self, wall: float) -> bool:
        """Inputs still arrive, and late: the node's own queues hold messages."""
        return self.lateness(wall) > self.behind_after

    def shed(self, lag: float) -> bool:
        return lag > self.shed_after
