"""The input contract every estimator shares (docs/API.md): one place for it.

Stamps are seconds, finite and never older than the last processed input;
controls are held (zero-order hold) until the next one; odometry poses become
body-frame increments between consecutive poses; an input that cannot be used
is dropped and counted by reason in the estimator's ``drops``, never raised.
:class:`OnlineEMSlam` and the baselines keep only what differs: how they
integrate motion up to a stamp.  (The node and the offline runner order the
streams before this, online_em_slam/pipeline/.)
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from .motion import odometry_increment


class MotionInput:
    """Stamp guard, held control and last odometry pose of one estimator."""

    def __init__(self, motion_model: str, drops: Counter, stamp: float | None = None) -> None:
        self.motion_model = motion_model
        self.drops = drops
        self.reset(stamp)

    def reset(self, stamp: float | None = None) -> None:
        self.last_stamp: float | None = None if stamp is None else float(stamp)
        self.held_control: np.ndarray | None = None
        self.last_odometry: np.ndarray | None = None

    def accept_stamp(self, stamp: float) -> bool:
        """Finite and not older than the last processed input (else counted)."""
        if not math.isfinite(stamp):
            self.drops["non_finite_stamp"] += 1
            return False
        if self.last_stamp is not None and stamp < self.last_stamp:
            self.drops["out_of_order"] += 1
            return False
        return True

    def control(self, stamp: float, control) -> np.ndarray | None:
        """The control (2,) if it can be used at ``stamp``, else None (counted)."""
        if self.motion_model == "odometry":
            self.drops["control_ignored_by_odometry_model"] += 1
            return None
        u = np.asarray(control, dtype=float).reshape(-1)
        if u.shape[0] < 2 or not np.all(np.isfinite(u[:2])):
            self.drops["non_finite_control"] += 1
            return None
        return u[:2].copy() if self.accept_stamp(stamp) else None

    def odometry(self, stamp: float, odom_pose) -> tuple[bool, np.ndarray | None]:
        """(usable, increment since the previous odometry pose or None).

        With a control-driven model the pose is only remembered, so switching
        sources later does not produce a jump; the increment is given only to
        the odometry model.
        """
        pose = np.asarray(odom_pose, dtype=float).reshape(-1)
        if pose.shape[0] < 3 or not np.all(np.isfinite(pose[:3])):
            self.drops["non_finite_odometry"] += 1
            return False, None
        if not self.accept_stamp(stamp):
            return False, None
        increment = None
        if self.motion_model == "odometry" and self.last_odometry is not None:
            increment = odometry_increment(self.last_odometry, pose[:3])
        self.last_odometry = pose[:3].copy()
        return True, increment
