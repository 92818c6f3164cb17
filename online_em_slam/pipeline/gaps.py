"""Loss detection in data time: a periodic stream with a hole lost messages.

Message queues (a full KEEP_LAST history, a best-effort link) lose messages
without telling the subscriber.  A stream whose first steps are regular
(odometry and control at a fixed rate, a detector that reports every scan,
empty or not) has a nominal period; a later step much longer than it means
messages were lost upstream, counted as ``<kind>_lost`` (the estimated number
of missing messages).  The nominal period is learnt from the first steps and
afterwards only from steps close to it, so sustained loss does not stretch it;
a stream that is not regular (a detector publishing only when it sees
something) is never judged.  Clouds are judged only once an empty one has come: a
detector that publishes every scan shows it by publishing the scans that saw nothing,
while one that publishes only what it saw (MRCLAM's camera: a cloud per frame with a
barcode read, frames 0.22-0.24 s apart) can start regular and then leave out frames
without losing anything (its "losses" were 300-1800 per robot in 600 s).  Lost means
never arrived: a message that comes
after its successors (an executor or a loaded link reorders) and falls into a
gap already counted is taken off that count.
"""
from __future__ import annotations

from collections import Counter, deque

import numpy as np

from .inputs import KIND_NAME, OBSERVATIONS

HISTORY = 64            # steps kept for the period estimate
MIN_STEPS = 16          # steps seen before a stream is judged regular or not
REGULAR = 1.3           # regular: the 90th percentile step is within this factor of the 10th
GAP_FACTOR = 1.8        # a step longer than this many periods is a gap
BAND = 0.3              # steps within +-30 % of the period keep refining it
REESTIMATE = 16         # the period is re-estimated every this many steps (a median per message is costly)
OPEN_GAPS = 8           # the latest gaps of a stream a late message may still fill


class _Stream:
    def __init__(self) -> None:
        self.last: float | None = None
        self.steps: deque = deque(maxlen=HISTORY)
        self.period: float | None = None        # None: still learning, or not regular
        self.regular: bool | None = None
        self.since = 0
        self.refused = 0                         # messages that came but could not be placed
        self.open_gaps: deque = deque(maxlen=OPEN_GAPS)   # [start, end, messages counted lost]
        self.reports_nothing_seen = False        # clouds: an empty one came (see the module docstring)

    def learn(self, step: float) -> None:
        self.steps.append(step)
        self.since += 1
        if self.regular is None and len(self.steps) >= MIN_STEPS:
            p10, p50, p90 = np.percentile(self.steps, (10, 50, 90))
            self.regular = bool(p10 > 0 and p90 <= REGULAR * p10)
            self.period = float(p50) if self.regular else None
            self.since = 0
        elif self.period is not None and self.since >= REESTIMATE:
            self.period = float(np.median(self.steps))
            self.since = 0


class GapDetector:
    def __init__(self, kinds: tuple[int, ...], drops: Counter | None = None) -> None:
        self.kinds = tuple(kinds)
        self.drops = drops if drops is not None else Counter()
        self.reset()

    def reset(self) -> None:
        self._streams = {k: _Stream() for k in self.kinds}

    def rebase(self) -> None:
        """The time line jumped (a confirmed jump): the next stamps start anew, the periods stay.
        A jump is a gap in the stamps, not messages that never arrived."""
        for stream in self._streams.values():
            stream.last, stream.refused = None, 0
            stream.open_gaps.clear()

    def period(self, kind: int) -> float | None:
        stream = self._streams.get(kind)
        return None if stream is None else stream.period

    def arrived_unusable(self, kind: int) -> None:
        """A message of ``kind`` came but its stamp cannot be placed (an outlier): not lost."""
        if kind in self._streams:
            self._streams[kind].refused += 1

    def observe(self, kind: int, stamp: float, empty: bool = False) -> int:
        """Note an input (``empty``: a cloud with no observation); returns the number of messages
        judged lost just before it."""
        stream = self._streams.get(kind)
        if stream is None:
            return 0
        stream.reports_nothing_seen |= empty
        last, stream.last = stream.last, (stamp if stream.last is None else max(stream.last, stamp))
        if last is None:
            return 0
        if stamp <= last:
            self._arrived_late(kind, stream, stamp)
            return 0
        step, refused, stream.refused = stamp - last, stream.refused, 0
        period = stream.period
        if period is None:
            if stream.regular is None:
                stream.learn(step)
            return 0
        if abs(step - period) <= BAND * period:
            stream.learn(step)
        if step <= GAP_FACTOR * period or (kind == OBSERVATIONS and not stream.reports_nothing_seen):
            return 0
        lost = int(round(step / period)) - 1 - refused
        if lost > 0:
            self.drops[f"{KIND_NAME[kind]}_lost"] += lost
            stream.open_gaps.append([last, stamp, lost])
        return max(lost, 0)

    def _arrived_late(self, kind: int, stream: _Stream, stamp: float) -> None:
        """A message older than its stream's newest: if it falls into a counted gap, it was not lost."""
        for gap in stream.open_gaps:
            if gap[0] < stamp < gap[1] and gap[2] > 0:
                gap[2] -= 1
                self.drops[f"{KIND_NAME[kind]}_lost"] -= 1
                return
