"""Time jumps versus lone bad stamps.

One input stamped 0, negative or far in the future must not move the time
line (a reset would wipe the map; a far-future stamp would make every later
input of its stream look out of order).  An input further than ``threshold``
from the current time line is held as a *candidate* jump: it becomes a jump
only when ``confirmations`` inputs agree with it (a bag played in a loop, a
clock that really jumped).  The candidate is refuted when a stream that took
part in it delivers an input on the old time line again; its inputs are then
dropped and counted as ``stamp_outlier``.  Inputs of other streams on the old
line do not refute it: a lagging stream may still deliver old stamps after a
real jump.  A /clock jump is confirmation enough; the node resets the guard then.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from .inputs import Input

ACCEPT, HOLD, JUMPED = "accept", "hold", "jumped"


@dataclass
class Verdict:
    action: str                                    # ACCEPT, HOLD or JUMPED
    released: list = field(default_factory=list)   # JUMPED: the inputs of the confirmed jump, in arrival order
    backward: bool = False                         # JUMPED: the new time line is behind the old one
    size: float = 0.0                              # JUMPED: how far (s)


class StampGuard:
    def __init__(self, threshold: float, confirmations: int = 3, drops: Counter | None = None) -> None:
        self.threshold = float(threshold)
        self.confirmations = max(int(confirmations), 1)
        self.drops = drops if drops is not None else Counter()
        self.reset()

    def reset(self) -> None:
        self._newest: dict[int, float] = {}        # per stream, accepted inputs only
        self._watched: dict[int, float] = {}       # per stream that is only watched (see note)
        self._candidate: list[Input] = []

    @property
    def holding(self) -> int:
        return len(self._candidate)

    def _reference(self, kind: int) -> float | None:
        own = self._newest.get(kind, self._watched.get(kind))
        return own if own is not None else (max(self._newest.values()) if self._newest else None)

    def is_jump(self, item: Input) -> bool:
        reference = self._reference(item.kind)
        if reference is None:
            return False
        # Ahead is judged against the newest stamp of any stream, the stream's own included: a
        # watched stream whose queue drains faster than the merged ones' (odometry ahead of the
        # controls under load) runs ahead of them on its own line, and is no jump.
        newest = max(max(self._newest.values(), default=reference), reference)
        if item.stamp > newest + self.threshold:
            return True
        # Behind is judged against the stream's own line only.  A stream's first inputs behind the
        # others' are a stream that lags (its subscription matched later, its queue read after
        # theirs), not a jump: taken for one, they restarted the robot's pose and time line
        # seconds into a run; accepted, the merge places them or counts them out of order.
        own = self._newest.get(item.kind, self._watched.get(item.kind))
        return own is not None and item.stamp < own - self.threshold

    def check(self, item: Input) -> Verdict:
        if not self.is_jump(item) and not self._joins_candidate(item):
            if any(c.kind == item.kind for c in self._candidate):
                self._refute()
            self.accept(item)
            return Verdict(ACCEPT)
        if self._candidate and not self._agrees(item):
            self._refute()
        self._candidate.append(item)
        if len(self._candidate) < self.confirmations:
            return Verdict(HOLD)
        return self._confirm()

    def _joins_candidate(self, item: Input) -> bool:
        """A stream's first input on the line of the jump being confirmed is part of that jump."""
        first = item.kind not in self._newest and item.kind not in self._watched
        return first and bool(self._candidate) and self._agrees(item)

    def _agrees(self, item: Input) -> bool:
        stamps = [c.stamp for c in self._candidate]
        return min(stamps) - self.threshold <= item.stamp <= max(stamps) + self.threshold

    def _refute(self) -> None:
        self.drops["stamp_outlier"] += len(self._candidate)
        self._candidate = []

    def _confirm(self) -> Verdict:
        held, self._candidate = self._candidate, []
        old = max(self._newest.values()) if self._newest else max(self._watched.values())
        backward = held[0].stamp < old
        # Only the streams that made the jump move to the new line.  The others keep their
        # own references: one that runs behind (a queue drained late) joins the new line when
        # its own stamps jump, instead of looking like yet another jump against the new
        # line's stamps (at a loop seam under load that flip-flopped, one reset each time).
        for kind in {item.kind for item in held}:
            self._newest.pop(kind, None)
        # A watched stream is never checked, so it never moves with a jump: after a jump back its
        # old line would refuse every new stamp, so it is judged anew.  After a jump ahead it keeps
        # its line: a stream that lags (the odometry behind a robot's sparse clouds, which the
        # guard takes for a jump ahead when its queues lag) would otherwise be judged against the
        # clouds' stamps and refused until it caught up (MRCLAM fleet at 5x: 28,000 per robot).
        if backward:
            self._watched = {}
        for item in held:
            self.accept(item)
        return Verdict(JUMPED, held, backward, abs(held[0].stamp - old))

    def note(self, kind: int, stamp: float) -> None:
        """An input of a stream that is not checked (watched only) was on the time line: later
        inputs of that stream are judged against it (until a jump is confirmed)."""
        previous = self._watched.get(kind)
        self._watched[kind] = stamp if previous is None else max(previous, stamp)

    def accept(self, item: Input) -> None:
        """``item`` is on the time line: later inputs of its stream are judged against it."""
        previous = self._newest.get(item.kind)
        self._newest[item.kind] = item.stamp if previous is None else max(previous, item.stamp)
