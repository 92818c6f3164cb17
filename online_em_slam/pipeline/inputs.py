"""What flows through the input path: one timestamped input of one stream, and its order."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import total_ordering
from typing import Any

# The input kinds: names only, their values carry no order.
ODOMETRY, OBSERVATIONS, CONTROL = 0, 1, 2
KIND_NAME = {ODOMETRY: "odometry", OBSERVATIONS: "observations", CONTROL: "control"}
MOTION_KINDS = (ODOMETRY, CONTROL)

# The tie rule, first to last, for inputs with equal stamps: odometry first (the pose
# at t is known before the scan at t is weighed), then observations, then a control,
# which holds from its stamp on (zero-order hold), so it must not move the scan at t.
TIE_ORDER = (ODOMETRY, OBSERVATIONS, CONTROL)
TIE_RANK = {kind: rank for rank, kind in enumerate(TIE_ORDER)}


def order_key(stamp: float, kind: int, seq: int = 0) -> tuple[float, int, int]:
    """The input order: by stamp, then by the tie rule (:data:`TIE_ORDER`), then by arrival."""
    return (stamp, TIE_RANK[kind], seq)


@total_ordering
@dataclass
class Input:
    """An input ordered by :func:`order_key` (stamp, tie rule, arrival); payload and arrival wall
    time neither order nor compare."""

    stamp: float
    kind: int
    seq: int = 0
    payload: Any = field(default=None, compare=False)
    wall: float = field(default=0.0, compare=False)      # monotonic arrival time (latency statistics)

    @property
    def key(self) -> tuple[float, int, int]:
        return order_key(self.stamp, self.kind, self.seq)

    def __lt__(self, other: "Input") -> bool:
        if not isinstance(other, Input):
            return NotImplemented
        return self.key < other.key

    @property
    def is_empty_cloud(self) -> bool:
        return self.kind == OBSERVATIONS and len(self.payload) == 0

    @property
    def refused_points(self) -> int:
        """Observations the cloud reader left out (already counted by reason; online_em_slam.messages.cloud)."""
        return int(getattr(self.payload, "refused_points", 0)) if self.kind == OBSERVATIONS else 0
