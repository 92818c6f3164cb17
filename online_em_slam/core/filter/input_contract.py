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

from ..config import MotionConfig, SensorConfig
from ..models.motion import odometry_increment
from ..types import Observations

# An odometry increment may exceed max_speed * dt by this much (m, rad) before it
# is implausible: stamps jitter, and odometry sources integrate between messages.
_ODOMETRY_SLACK = (0.5, 0.5)
# Implausible odometry poses in a row that confirm a jump of the odometry frame
# (a driver restart): the next pose is then a new reference, without motion.
_CONFIRM_ODOMETRY_JUMP = 3
_MAX_STEERING = 1.5   # rad: a steering angle beyond this is not a car's


class MotionInput:
    """Stamp guard, held control and last odometry pose of one estimator."""

    def __init__(self, motion: MotionConfig, drops: Counter, stamp: float | None = None) -> None:
        self.motion = motion
        self.drops = drops
        self.reset(stamp)

    def reset(self, stamp: float | None = None) -> None:
        self.last_stamp: float | None = None if stamp is None else float(stamp)
        self.held_control: np.ndarray | None = None
        # Controls still in the drive's dead time: (time they take effect, control), in order.
        self.scheduled: tuple[tuple[float, np.ndarray], ...] = ()
        self.last_odometry: np.ndarray | None = None
        self._last_odometry_stamp: float | None = None
        self._implausible_odometry = 0

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
        if self.motion.uses_odometry:
            self.drops["control_ignored_by_odometry_model"] += 1
            return None
        u = np.asarray(control, dtype=float).reshape(-1)
        if u.shape[0] < 2 or not (math.isfinite(u[0]) and math.isfinite(u[1])):
            self.drops["non_finite_control"] += 1
            return None
        if not self._plausible_control(u):
            self.drops["implausible_control"] += 1
            return None
        return u[:2].copy() if self.accept_stamp(stamp) else None

    def hold(self, stamp: float, u: np.ndarray, delay: float | None = None) -> None:
        """``u`` takes over from the held control ``delay`` s (default ``motion.control_delay``, the
        drive's dead time) after ``stamp``, at once without one; :meth:`held_segments` switches to
        it when the time comes."""
        delay = self.motion.control_delay if delay is None else delay
        if delay > 0.0:
            self.scheduled = self.scheduled + ((float(stamp) + delay, u),)
        else:
            self.held_control = u

    def held_segments(self, stamp: float) -> list[tuple[np.ndarray, float]]:
        """The held controls from the last stamp up to ``stamp`` as (control, dt) segments, each
        scheduled control taking over at its time; the last stamp becomes ``stamp``."""
        segments, t = [], self.last_stamp
        while self.scheduled and self.scheduled[0][0] <= stamp:
            (when, u), self.scheduled = self.scheduled[0], self.scheduled[1:]
            if when > t and self.held_control is not None:
                segments.append((self.held_control, when - t))
            t, self.held_control = max(t, when), u
        if stamp > t and self.held_control is not None:
            segments.append((self.held_control, stamp - t))
        self.last_stamp = stamp
        return segments

    def _plausible_control(self, u: np.ndarray) -> bool:
        if abs(u[0]) > self.motion.max_speed:
            return False
        if self.motion.motion_input == "yaw_rate":
            return abs(u[1]) <= self.motion.max_yaw_rate
        return abs(u[1]) <= _MAX_STEERING

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
        if self.last_odometry is not None:
            increment = odometry_increment(self.last_odometry, pose[:3])
            if not self._plausible_increment(increment, stamp):
                return self._implausible(pose, stamp)
        self._implausible_odometry = 0
        self.last_odometry, self._last_odometry_stamp = pose[:3].copy(), float(stamp)
        return True, increment if self.motion.uses_odometry else None

    def odometry_motion(self, stamp: float, odom_pose) -> tuple[bool, np.ndarray | None, float]:
        """:meth:`odometry` plus the time since the last processed input, the step the
        increment is spread over."""
        previous = self.last_stamp
        usable, increment = self.odometry(stamp, odom_pose)
        return usable, increment, 0.0 if previous is None else float(stamp) - previous

    def _plausible_increment(self, increment: np.ndarray, stamp: float) -> bool:
        since = self._last_odometry_stamp
        dt = 0.0 if since is None else max(float(stamp) - since, 0.0)
        return (np.hypot(increment[0], increment[1]) <= self.motion.max_speed * dt + _ODOMETRY_SLACK[0]
                and abs(increment[2]) <= self.motion.max_yaw_rate * dt + _ODOMETRY_SLACK[1])

    def _implausible(self, pose: np.ndarray, stamp: float) -> tuple[bool, None]:
        """Drop a pose the vehicle cannot have reached; several in a row are a jump of the
        odometry frame itself, taken as the new reference without motion."""
        self._implausible_odometry += 1
        if self._implausible_odometry < _CONFIRM_ODOMETRY_JUMP or not np.all(np.abs(pose[:2]) < 1e12):
            self.drops["implausible_odometry"] += 1
            return False, None
        self.drops["odometry_jump_reset"] += 1
        self._implausible_odometry = 0
        self.last_odometry, self._last_odometry_stamp = pose[:3].copy(), float(stamp)
        return True, None


def usable_observations(obs: Observations, sensor: SensorConfig, cap: int) -> tuple[np.ndarray, dict[str, int]]:
    """(mask of the observations an estimator uses, counts of the others by reason).

    Usable: finite, range >= 0, valid per-point stds, range within [min_range, max_range];
    of more than ``cap`` usable points (a cloud far beyond any sensor's count would cost
    memory and time in the association) the first ``cap`` are kept, the rest counted.
    """
    finite = np.isfinite(obs.ranges) & np.isfinite(obs.bearings)
    valid = finite & (obs.ranges >= 0)
    std_ok = obs.valid_std()
    in_range = valid & std_ok & (obs.ranges >= max(sensor.min_range, 0.0)) & (obs.ranges <= sensor.max_range)
    dropped: dict[str, int] = {}
    if not in_range.all():                    # else every point is usable: nothing to count
        for reason, mask in (("invalid_observation", ~valid), ("invalid_std", valid & ~std_ok),
                             ("observation_out_of_range", valid & std_ok & ~in_range)):
            if mask.any():
                dropped[reason] = int(mask.sum())
    if in_range.sum() > cap:
        beyond = np.flatnonzero(in_range)[cap:]
        in_range[beyond] = False
        dropped["too_many_observations"] = int(beyond.size)
    return in_range, dropped
