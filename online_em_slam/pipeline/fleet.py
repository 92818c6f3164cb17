"""The input path of a fleet: one :class:`~.input_pipeline.InputPipeline` per robot into one
:class:`~online_em_slam.core.fleet.slam.FleetSlam`.

Each robot's inputs are checked, ordered and fed as a single robot's are (stamp checks,
the ordered merge of its motion and observation streams within ``input_delay``, the
feeder's decisions: empty clouds, scans before the first motion input, and
``filter.minimum_travel_*`` on that robot's own travel); one robot's silence holds no
other back.  The feeder sees robot r as a single-robot estimator (:class:`RobotView`).
A failing input is undone on the whole fleet (the map is shared): one
:class:`~.rollback.Rollback` of the fleet, which every robot's feeder calls through
(:class:`RobotRollback`), so a restore replays every robot's inputs since the copy, in
the order they were applied.
"""
from __future__ import annotations

from collections import Counter
from typing import Callable

from .feeder import Fed
from .input_pipeline import InputPipeline
from .inputs import Input
from .rollback import Rollback

FleetApplied = Callable[[int, Input, Fed], None]


class RobotView:
    """Robot ``robot`` of ``fleet`` with the single-robot estimator's interface (what the feeder calls)."""

    def __init__(self, fleet, robot: int) -> None:
        self.fleet, self.robot = fleet, int(robot)

    @property
    def config(self):
        return self.fleet.config

    @property
    def drops(self) -> Counter:
        return self.fleet.robot(self.robot).drops

    def add_control(self, stamp: float, control) -> bool:
        return self.fleet.add_control(self.robot, stamp, control)

    def add_odometry(self, stamp: float, odom_pose) -> bool:
        return self.fleet.add_odometry(self.robot, stamp, odom_pose)

    def add_observations(self, stamp: float, observations):
        return self.fleet.add_observations(self.robot, stamp, observations)

    def pose(self):
        return self.fleet.pose(self.robot)

    def landmarks(self, confirmed_only: bool = False):
        return self.fleet.landmarks(confirmed_only)


class RobotRollback:
    """Robot ``robot``'s calls through the fleet's one rollback (``call(method, *args)`` becomes
    ``fleet.method(robot, *args)``)."""

    def __init__(self, shared: Rollback, robot: int) -> None:
        self.shared, self.robot = shared, int(robot)

    def call(self, method: str, *args):
        return self.shared.call(method, self.robot, *args)

    def checkpoint(self) -> None:
        self.shared.checkpoint()

    def restore(self) -> None:
        self.shared.restore()


class FleetPipeline:
    """Every robot's inputs into ``fleet``: ``push(robot, kind, stamp, payload, wall)``; ``on_applied(robot,
    item, fed)`` once per applied input (the settings as :class:`InputPipeline`'s)."""

    def __init__(self, fleet, motion_source: str, input_delay: float, jump_threshold: float, *,
                 restart_on_jump_back: bool = False, on_applied: FleetApplied | None = None) -> None:
        self.fleet = fleet
        self.rollback = Rollback(fleet)
        self.pipelines = [
            InputPipeline(RobotView(fleet, r), motion_source, input_delay, jump_threshold,
                          restart_on_jump_back=restart_on_jump_back,
                          on_applied=None if on_applied is None else self._callback(on_applied, r),
                          rollback=lambda _view, r=r: RobotRollback(self.rollback, r))
            for r in range(fleet.n_robots)]

    @staticmethod
    def _callback(on_applied: FleetApplied, robot: int):
        return lambda item, fed: on_applied(robot, item, fed)

    def push(self, robot: int, kind: int, stamp: float, payload, wall: float) -> None:
        self.pipelines[robot].push(kind, stamp, payload, wall)

    def flush(self) -> None:
        """Apply everything still queued (end of a bag), robot by robot."""
        for pipeline in self.pipelines:
            pipeline.flush()

    def drops(self, robot: int) -> Counter:
        """Robot ``robot``'s inputs refused by its path and feeder, by reason."""
        return self.pipelines[robot].drops
