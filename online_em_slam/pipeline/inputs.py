"""What flows through the input path: one timestamped input of one stream."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

# Kinds double as the tie rule: at equal stamps odometry comes first (the pose at t
# is known before the scan at t is weighed), then observations, then a control,
# which holds from its stamp on (zero-order hold), so it must not move the scan at t.
ODOMETRY, OBSERVATIONS, CONTROL = 0, 1, 2
KIND_NAME = {ODOMETRY: "odometry", OBSERVATIONS: "observations", CONTROL: "control"}
MOTION_KINDS = (ODOMETRY, CONTROL)


@dataclass(order=True)
class Input:
    """An input ordered by (stamp, kind, arrival); payload and arrival wall time do not order."""

    stamp: float
    kind: int
    seq: int = 0
    payload: Any = field(default=None, compare=False)
    wall: float = field(default=0.0, compare=False)      # monotonic arrival time (latency statistics)

    @property
    def is_empty_cloud(self) -> bool:
        return self.kind == OBSERVATIONS and len(self.payload) == 0

    @property
    def refused_points(self) -> int:
        """Observations the cloud reader left out (already counted by reason; online_em_slam.cloud)."""
        return int(getattr(self.payload, "refused_points", 0)) if self.kind == OBSERVATIONS else 0
