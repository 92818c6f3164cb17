"""Released inputs into an estimator: the one place that decides what drives what.

Works with every estimator of the package (``add_control``, ``add_odometry``,
``add_observations``, ``pose``).  Empty clouds carry no observation and are
not fed (``empty_cloud``, unless the cloud reader emptied it: its points are
already counted by reason, ``invalid_id`` and the like); observations before the first
motion input have no pose to hang on (``no_motion_input``); a scan before the robot has
travelled ``filter.minimum_travel_*`` since the last used one is not used
(``minimum_travel``, travel.py).  The trajectory is the estimator's pose after each
observation message, once per estimator stamp: the node publishes it
as ``~/path`` and the offline runner writes it as trajectory.csv, so the two
are comparable point for point.

An input whose application raises is dropped (``internal_error``, its error in
``Fed.error``) and leaves no trace: :class:`~.rollback.Rollback` restores the
estimator to its state before it, so one bad input never stops the estimator.  Inputs it
applied again and that raised then (a failure beyond the inputs) are lost and counted
(``reapply_failed``).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

from .inputs import CONTROL, ODOMETRY, Input
from .rollback import Rollback
from .travel import MinimumTravel


@dataclass
class Fed:
    """What applying one input did."""

    moved: bool = False              # a motion input was used
    report: object = None            # StepReport of an observation update, else None
    trajectory_point: tuple | None = None   # (stamp, x, y, yaw) appended to the trajectory
    error: Exception | None = None   # the input raised: dropped, the estimator as before it


def rollback_of(estimator):
    """The estimator's own rollback where it has one (a fleet robot's undoes the whole fleet, whose
    map it shares: pipeline/fleet.py), else a :class:`~.rollback.Rollback` of it."""
    make_rollback = getattr(estimator, "make_rollback", None)
    return make_rollback() if callable(make_rollback) else Rollback(estimator)


class Feeder:
    """Applies one input at a time to ``estimator`` through its rollback (:func:`rollback_of`)."""

    def __init__(self, estimator, motion_source: str, drops: Counter | None = None) -> None:
        self.estimator = estimator
        self.motion_kind = ODOMETRY if motion_source == "odom" else CONTROL
        self.drops = drops if drops is not None else Counter()
        self.reset(estimator)

    def reset(self, estimator) -> None:
        """Feed ``estimator`` from now on; call after any change made to it outside :meth:`apply`."""
        self.estimator = estimator
        self.rollback = rollback_of(estimator)
        self.motion_seen = False
        self.last_point_stamp: float | None = None
        self.travel = MinimumTravel.from_config(getattr(estimator, "config", None))

    def apply(self, item: Input, use_observations: bool = True) -> Fed:
        """Apply ``item``; ``use_observations`` False sheds an observation update (overload)."""
        try:
            if item.kind == self.motion_kind:
                return self._motion(item)
            if item.kind != ODOMETRY and item.kind != CONTROL:
                return self._observations(item, use_observations)
        except Exception as error:  # noqa: BLE001 - one bad input must never stop the estimator
            self.drops["internal_error"] += 1
            lost = self.rollback.take_lost()
            if lost:
                self.drops["reapply_failed"] += lost
            return Fed(error=error)
        return Fed()                 # odometry while control drives the motion: pose bookkeeping only

    def _motion(self, item: Input) -> Fed:
        add = "add_odometry" if item.kind == ODOMETRY else "add_control"
        moved = bool(self.rollback.call(add, item.stamp, item.payload))
        self.motion_seen |= moved
        return Fed(moved=moved)

    def _observations(self, item: Input, use_observations: bool) -> Fed:
        fed = Fed()
        if item.is_empty_cloud:
            if not item.refused_points:      # emptied by the reader: counted once, under its reasons
                self.drops["empty_cloud"] += 1
        elif not self.motion_seen:
            self.drops["no_motion_input"] += 1
            return fed
        elif not use_observations:
            self.drops["overload"] += 1
        elif self.travel.enabled and not self.travel.due(self.rollback.call("pose").mean):
            self.drops["minimum_travel"] += 1
        else:
            fed.report = self.rollback.call("add_observations", item.stamp, item.payload)
            if self.travel.enabled:
                self.travel.used(self.rollback.call("pose").mean)
        fed.trajectory_point = self._trajectory_point(item.stamp)
        return fed

    def _trajectory_point(self, stamp: float) -> tuple | None:
        estimate = self.rollback.call("pose")
        t = estimate.stamp if estimate.stamp is not None else stamp
        if self.last_point_stamp is not None and t <= self.last_point_stamp:
            return None
        self.last_point_stamp = float(t)
        return (float(t), *map(float, estimate.mean[:3]))
