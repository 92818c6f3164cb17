"""Fleet mode's names: each robot's topics and frames (nav2's multi-robot conventions).

Robot ``robot1`` of a node in namespace ``/ns`` subscribes to ``robot1/odom``,
``robot1/control``, ``robot1/landmark_observations`` (the single node's relative
topic names under the robot's namespace: ``/ns/robot1/odom``), publishes
``robot1/pose``, ``robot1/path``, ``robot1/particles`` (and, without TF,
``robot1/map_to_odom``), and its frames are the configured ones prefixed with the
robot (``robot1/odom``, ``robot1/base_link``, ``robot1/<sensor_frame>``), as nav2's
multi-robot launch does with ``frame_prefix``.  The map frame is the fleet's one
``map_frame``.  Absolute names (``/tf``, ``/diagnostics``) are shared.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


def prefixed(robot: str, name: str) -> str:
    """``name`` under ``robot`` (``odom`` -> ``robot1/odom``); absolute names stay as they are."""
    if not name or name.startswith("/"):
        return name
    return f"{robot}/{name.removeprefix('~/')}"


@dataclass(frozen=True)
class RobotNames:
    """The names of one robot of the fleet (``robot``: its namespace in ``robots``)."""

    robot: str

    def topic(self, name: str) -> str:
        """An input topic (relative parameter value) or an output of the single node (``~/pose``)."""
        return prefixed(self.robot, name)

    def frame(self, name: str) -> str:
        return prefixed(self.robot, name)

    def settings(self, settings):
        """The node's settings as the robot's input and output code sees them: its topics and frames."""
        return replace(settings, odom_topic=self.topic(settings.odom_topic),
                       control_topic=self.topic(settings.control_topic),
                       observations_topic=self.topic(settings.observations_topic),
                       odom_frame=self.frame(settings.odom_frame), base_frame=self.frame(settings.base_frame),
                       sensor_frame=self.frame(settings.sensor_frame))


def fleet_names(settings) -> list[RobotNames]:
    return [RobotNames(robot) for robot in settings.robots]


def initial_poses(settings) -> np.ndarray:
    """(R, 3) initial poses: ``initial_poses`` robot after robot, else every robot at ``initial_pose.*``."""
    if settings.initial_poses:
        return np.asarray(settings.initial_poses, dtype=float).reshape(-1, 3)
    return np.tile(np.asarray(settings.initial_pose, dtype=float), (len(settings.robots), 1))
