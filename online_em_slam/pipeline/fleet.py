"""The input path of a fleet: one :class:`~.input_pipeline.InputPipeline` per robot into one
:class:`~online_em_slam.core.fleet.slam.FleetSlam`.

Each robot's inputs are checked, ordered and fed as a single robot's are (stamp checks,
the ordered merge of its motion and observation streams within ``input_delay``, the
feeder's decisions: empty clouds, scans before the first motion input, and
``filter.minimum_travel_*`` on that robot's own travel); one robot's silence holds no
other back.  The feeder sees robot r as a single-robot estimator (:class:`RobotView`).
A failing input is undone on the whole fleet (the map is shared): one
:class:`~.rollback.Rollback` of the fleet, which every robot's feeder calls through
(:class:`RobotRollback`, from :meth:`RobotView.make_rollback`), so a restore replays every
robot's inputs since the copy, in the order they were applied.  The node's fleet mode
(ros/fleet_*.py) feeds its robots' pipelines through the same views.
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
    """Robot ``robot`` of ``fleet`` with the single-robot estimator's interface, for the feeder
    and the node: inputs and the pose go through the fleet, :meth:`make_rollback` gives the
    fleet's shared rollback (``shared``), and what is not defined here (``particles``,
    ``last_stamp``, ``restart_time_line``, ``drops`` ...) is the robot's filter's, looked up
    at each use (a rollback replaces the filter objects)."""

    def __init__(self, fleet, robot: int, shared: Rollback | None = None) -> None:
        self.fleet, self.robot = fleet, int(robot)
        self.shared = shared if shared is not None else Rollback(fleet)

    @property
    def config(self):
        return self.fleet.config

    def filter(self):
        """The robot's own filter (core/fleet/robot.py)."""
        return self.fleet.robot(self.robot)

    def make_rollback(self) -> "RobotRollback":
        """The feeder's rollback (feeder.rollback_of): the fleet's, checkpointed now (the fleet may
        have been changed from outside, a restarted time line)."""
        self.shared.checkpoint()
        return RobotRollback(self.shared, self.robot)

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

    def revised_trajectory(self):
        return self.fleet.revised_trajectory(self.robot)

    def __getattr__(self, name: str):
        if name.startswith("__") or name in ("fleet", "robot", "shared"):
            raise AttributeError(name)
        return getattr(self.fleet.robot(self.robot), name)


def robot_views(fleet) -> list[RobotView]:
    """One view per robot of ``fleet``, sharing one rollback of it."""
    shared = Rollback(fleet)
    return [RobotView(fleet, robot, shared) for robot in range(fleet.n_robots)]


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

    def take_lost(self) -> int:
        return self.shared.take_lost()


class FleetPipeline:
    """Every robot's inputs into ``fleet``: ``push(robot, kind, stamp, payload, wall)``; ``on_applied(robot,
    item, fed)`` once per applied input (the settings as :class:`InputPipeline`'s)."""

    def __init__(self, fleet, motion_source: str, input_delay: float, jump_threshold: float, *,
                 restart_on_jump_back: bool = False, on_applied: FleetApplied | None = None) -> None:
        self.fleet = fleet
        self.pipelines = [
            InputPipeline(view, motion_source, input_delay, jump_threshold,
                          restart_on_jump_back=restart_on_jump_back,
                          on_applied=None if on_applied is None else self._callback(on_applied, r))
            for r, view in enumerate(robot_views(fleet))]

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
