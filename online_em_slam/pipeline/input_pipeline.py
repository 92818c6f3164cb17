"""The input pipeline: decoded inputs in, estimator updates out, one way.

    push / heard / release / flush -> InputPath (stamp checks, loss, merge)
                                   -> load shedding (LoadMonitor)
                                   -> Feeder (with its Rollback) -> estimator
                                   -> on_applied(item, fed) per applied input,
                                      on_settled(used, observed) per batch

The ROS node and the offline runner both own one :class:`InputPipeline` and
hand it every input they decode; neither touches the path or the feeder in
between, so both feed their estimator the identical sequence.  What the
caller does with an applied input (publish, record a trajectory) happens in
its callbacks.  A confirmed time jump is reported through ``on_jump(verdict,
restarted)`` before the inputs it released are applied; when it restarted the
time line, the callback restarts the estimator (:meth:`restart`).
"""
from __future__ import annotations

import time
from collections import Counter
from typing import Callable

from .feeder import Fed, Feeder
from .input_path import InputPath
from .inputs import CONTROL, OBSERVATIONS, ODOMETRY, Input
from .load import LoadMonitor
from .stamp_guard import Verdict

Applied = Callable[[Input, Fed], None]
Settled = Callable[[bool, bool], None]
Jumped = Callable[[Verdict, bool], None]


def merged_streams(motion_source: str) -> tuple[int, ...]:
    """The input streams that are merged: the motion input that drives the estimator and the observations."""
    return (ODOMETRY if motion_source == "odom" else CONTROL, OBSERVATIONS)


class InputPipeline:
    """Owns the input path, the feeder and load shedding of one estimator.

    ``shedding``: skip observation updates while the load is above the limit or
    while the inputs wait longer than ``max_wait`` (s) in the transport's queues
    (best-effort inputs that would otherwise overflow; never for lossless
    inputs).  ``clock``: wall time for the load (seconds, monotonic).
    """

    def __init__(self, estimator, motion_source: str, input_delay: float, jump_threshold: float, *,
                 restart_on_jump_back: bool = True, shedding: bool = False, max_wait: float = 0.0,
                 on_applied: Applied | None = None, on_settled: Settled | None = None,
                 on_jump: Jumped | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.motion_kind = merged_streams(motion_source)[0]
        self.path = InputPath(merged_streams(motion_source), input_delay, jump_threshold,
                              restart_on_jump_back=restart_on_jump_back)
        self.feeder = Feeder(estimator, motion_source, self.path.drops)
        self.load = LoadMonitor()
        self.max_load = 0.0
        self.shedding = shedding
        self.max_wait = float(max_wait)
        self.lag = 0.0                 # how long the last odometry or control message waited (s)
        self.on_applied = on_applied
        self.on_settled = on_settled
        self.on_jump = on_jump
        self.clock = clock

    # ------------------------------------------------------------------ state
    @property
    def drops(self) -> Counter:
        """Inputs refused by the path and the feeder, by reason."""
        return self.path.drops

    @property
    def estimator(self):
        return self.feeder.estimator

    @property
    def newest(self) -> float | None:
        return self.path.newest

    def __len__(self) -> int:
        return len(self.path)

    def current_load(self, now: float | None = None) -> float:
        """Share of the last second spent handling inputs, at ``now`` (clock time; default: the clock)."""
        return self.load.load(self.clock() if now is None else now)

    def set_input_delay(self, seconds: float) -> None:
        """How long the merge waits for a silent stream (the node's ``input_delay``, changed at run time)."""
        self.path.sequencer.silence = float(seconds)

    # ------------------------------------------------------------------ inputs
    def push(self, kind: int, stamp: float, payload, wall: float) -> None:
        """An input of a merged stream; applies whatever it releases."""
        pushed = self.path.push(kind, stamp, payload, wall)
        if pushed.jump is not None and self.on_jump is not None:
            self.on_jump(pushed.jump, pushed.restarted)
        self._apply(pushed.released)

    def heard(self, kind: int, stamp: float, wall: float) -> None:
        """A message with a usable stamp but an unusable payload: its stream is alive up to ``stamp``."""
        self._apply(self.path.heard(kind, stamp, wall))

    def release(self, wall: float) -> None:
        """Apply the inputs that became safe because a stream went silent (call periodically)."""
        self._apply(self.path.release(wall))

    def flush(self) -> None:
        """Apply everything still queued (end of a bag)."""
        self._apply(self.path.flush())

    def on_time_line(self, kind: int, stamp: float) -> bool:
        return self.path.on_time_line(kind, stamp)

    def watch(self, kind: int, stamp: float) -> None:
        """A periodic stream that is not merged: see :meth:`InputPath.watch`."""
        self.path.watch(kind, stamp)

    def read_ahead_span(self) -> float:
        """How far in stamps one stream's queue may be read ahead of the others' (s): the merge
        restores stamp order, and half the jump threshold keeps a stream read later from looking
        like a jump back; 0 with the merge off (inputs used in arrival order)."""
        return 0.5 * self.path.guard.threshold if self.path.sequencer.silence > 0 else 0.0

    def waited(self, seconds: float) -> None:
        """A motion or odometry message waited ``seconds`` in its queue before it was read."""
        self.lag = seconds

    def overdue(self, waited: float) -> bool:
        """An observation that waited ``waited`` s, or one read while the last motion message had
        waited longer than ``max_wait``, is shed unread: an update costs more than all the motion
        inputs queued behind it, which would otherwise overflow their queue or go stale.
        The executor reads every subscription in turn, so the motion queues, the busier, lag
        first; the observations' own wait stays short (``max_wait`` 0: never)."""
        return self.shedding and 0.0 < self.max_wait < max(waited, self.lag)

    def shed(self, kind: int, stamp: float, wall: float) -> None:
        """An input shed unread (``overload``): its stamp still advances its stream."""
        self.drops["overload"] += 1
        self.heard(kind, stamp, wall)

    def busy(self, end: float, seconds: float) -> None:
        """``seconds`` of input handling that ended at ``end`` (clock time): the load."""
        self.load.add(end, seconds)

    # ------------------------------------------------------------------ time line and estimator
    def restart(self, estimator, keep_inputs: bool = False) -> None:
        """Feed ``estimator`` from now on (after a reset or any change made to it outside the pipeline);
        ``keep_inputs``: the path already restarted its time line (a confirmed jump back)."""
        if not keep_inputs:
            self.path.reset()
        self.feeder.reset(estimator)

    def checkpoint(self) -> None:
        """The estimator was changed from outside (a loaded map, a set pose): a failing input later
        returns to this state."""
        self.feeder.rollback.checkpoint()

    def forget_time_line(self) -> None:
        """Trust the next stamps as they come (after a pause)."""
        self.path.forget_time_line()

    # ------------------------------------------------------------------ into the estimator
    def _apply(self, released: list) -> None:
        if not released:
            return
        used = observed = False
        for item in released:
            fed = self._feed(item)
            used |= fed.moved or fed.report is not None
            observed |= fed.report is not None
            if self.on_applied is not None:
                self.on_applied(item, fed)
        if self.on_settled is not None:
            self.on_settled(used, observed)

    def _feed(self, item: Input) -> Fed:
        load = self.current_load() if item.kind == OBSERVATIONS else 0.0
        self.max_load = max(self.max_load, load)
        shed = self.shedding and load > self.load.limit
        return self.feeder.apply(item, use_observations=not shed)
