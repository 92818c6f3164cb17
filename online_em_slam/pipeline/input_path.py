"""The input path shared by the node and the offline runner: inputs in arrival
order go in, inputs in (stamp, tie rule, arrival) order come out (inputs.order_key).

    stamp check -> StampGuard (lone bad stamps, confirmed jumps)
                -> GapDetector (messages lost upstream, counted)
                -> Sequencer (per-stream watermark merge)

Every refusal is counted in :attr:`drops` by reason.  A confirmed backward
jump (a bag played in a loop) restarts the path when ``restart_on_jump_back``
is set; the caller then restarts its estimator before using the released inputs.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

from .gaps import GapDetector
from .inputs import MOTION_KINDS, Input
from .sequencer import Sequencer
from .stamp_guard import HOLD, JUMPED, StampGuard, Verdict


@dataclass
class Pushed:
    released: list = field(default_factory=list)   # inputs to use now, in order
    restarted: bool = False                        # a confirmed jump back restarted the time line
    jump: Verdict | None = None                    # the confirmed jump, if any


class InputPath:
    def __init__(self, streams: tuple[int, ...], silence: float, jump_threshold: float,
                 restart_on_jump_back: bool = True, confirmations: int = 3) -> None:
        self.drops: Counter = Counter()
        self.streams = tuple(streams)
        self.restart_on_jump_back = restart_on_jump_back
        self.guard = StampGuard(jump_threshold, confirmations, self.drops)
        self.gaps = GapDetector(tuple(set(MOTION_KINDS) | set(self.streams)), self.drops)
        self.sequencer = Sequencer(self.streams, silence, self.drops)

    def reset(self) -> None:
        """Forget the time line (estimate reset, clock jump, pause); keeps the counters."""
        self.guard.reset()
        self.gaps.reset()
        self.sequencer.reset()

    def forget_time_line(self) -> None:
        """Trust the next stamps as they come (after a pause): no jump, no loss across the pause."""
        self.guard.reset()
        self.gaps.reset()

    def __len__(self) -> int:
        return len(self.sequencer) + self.guard.holding

    @property
    def newest(self) -> float | None:
        return self.sequencer.newest

    def push(self, kind: int, stamp: float, payload, wall: float) -> Pushed:
        if not math.isfinite(stamp):
            self.drops["non_finite_stamp"] += 1
            return Pushed(self.sequencer.release(wall))
        item = Input(float(stamp), kind, payload=payload)
        verdict = self.guard.check(item)
        if verdict.action == HOLD:
            self.gaps.arrived_unusable(kind)
            return Pushed(self.sequencer.release(wall))
        if verdict.action == JUMPED:
            return self._jumped(verdict, wall)
        return Pushed(self._sequence(item, wall))

    def heard(self, kind: int, stamp: float, wall: float) -> list[Input]:
        """A message with a usable stamp but an unusable payload (or one shed unread): its stream is
        alive up to ``stamp``, and later stamps of the stream are judged against it."""
        item = Input(float(stamp), kind)
        if math.isfinite(stamp) and not self.guard.is_jump(item):
            self.guard.accept(item)
            self.gaps.observe(kind, float(stamp))      # a message that came is not a lost one
            self.sequencer.heard(kind, float(stamp), wall)
        return self.sequencer.release(wall)

    def on_time_line(self, kind: int, stamp: float) -> bool:
        """``stamp`` is finite and not a candidate jump (a lone bad stamp the guard would hold)."""
        return math.isfinite(stamp) and not self.guard.is_jump(Input(float(stamp), kind))

    def watch(self, kind: int, stamp: float) -> None:
        """A periodic stream that is not merged (odometry while control drives the motion): count its
        losses, and judge its next stamps against its own (a stream that runs behind the merged ones
        under load is not a time jump)."""
        if math.isfinite(stamp):
            self.gaps.observe(kind, float(stamp))
            self.guard.note(kind, float(stamp))

    def _sequence(self, item: Input, wall: float) -> list[Input]:
        self.gaps.observe(item.kind, item.stamp, item.payload is not None and item.is_empty_cloud)
        return self.sequencer.push(item, wall)

    def _jumped(self, verdict: Verdict, wall: float) -> Pushed:
        restart = verdict.backward and self.restart_on_jump_back
        if restart:
            self.gaps.reset()
            self.sequencer.reset()
        else:
            self.gaps.rebase()
        released = []
        for item in verdict.released:
            released += self._sequence(item, wall)
        return Pushed(released, restart, verdict)

    def release(self, wall: float) -> list[Input]:
        """Inputs that became safe because a stream went silent (call periodically)."""
        return self.sequencer.release(wall)

    def flush(self) -> list[Input]:
        return self.sequencer.flush()
