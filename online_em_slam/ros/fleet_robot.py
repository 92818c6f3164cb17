"""One robot of the fleet node: the single node's inputs and outputs, seen through :class:`RobotView`.

:class:`RobotView` stands for the node towards one robot's
:class:`~.inputs.Inputs` and :class:`~.outputs.Outputs`: its ``settings`` carry
the robot's topics and frames (fleet_names.py), its ``slam`` is the robot's feed
of the shared :class:`~..core.fleet.slam.FleetSlam`, publishers are created under
the robot's namespace, drops are counted per robot, and a time jump of the robot's
inputs restarts only its pose and time line.  Everything else (lock, pause, clock,
logger, subscriptions) is the node's.
"""
from __future__ import annotations

from collections import Counter

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.qos import QoSProfile

from .fleet_names import RobotNames
from .inputs import Inputs
from .outputs import Outputs
from .services import set_pose_from


class RobotView:
    """The node as robot ``index`` (``names``) sees it; ``feed``: its pipeline.fleet.RobotView."""

    def __init__(self, node, index: int, names: RobotNames, feed, initial_pose) -> None:
        self._node = node
        self.index = index
        self.names = names
        self.slam = feed
        self.initial_pose = initial_pose
        self.settings = names.settings(node.settings)
        self.drops: Counter = Counter()

    def __getattr__(self, name: str):
        if name.startswith("__") or name == "_node":
            raise AttributeError(name)
        return getattr(self._node, name)

    def create_publisher(self, msg_type, topic: str, qos, **kwargs):
        return self._node.create_publisher(msg_type, self.names.topic(topic), qos, **kwargs)

    def reset(self, reason: str, keep_inputs: bool = False, keep_map: bool = False) -> None:
        """A time jump (``keep_map``) restarts this robot's pose and time line; anything else the node's."""
        if not keep_map:
            self._node.reset(reason, keep_inputs=keep_inputs)
            return
        with self._node.lock:
            self.slam.restart_time_line(self.initial_pose)
            self.inputs.pipeline.restart(self.slam, keep_inputs=keep_inputs)
            self.outputs.reset()
            self._node.diagnostics.count_reset()
            self._node.get_logger().warning(f"{self.names.robot}: estimate reset: {reason}; the map is kept")


class RobotDiagnostics:
    """The node's diagnostics as one robot's inputs and outputs use them: the robot's
    well-formed inputs are also counted for it (``inputs.<robot>`` in /diagnostics)."""

    def __init__(self, diagnostics) -> None:
        self._diagnostics = diagnostics
        self.inputs = 0

    def count_input(self) -> None:
        self.inputs += 1
        self._diagnostics.count_input()

    def __getattr__(self, name: str):
        if name.startswith("__") or name == "_diagnostics":
            raise AttributeError(name)
        return getattr(self._diagnostics, name)


class FleetRobotIO:
    """Robot ``index``'s view, outputs (pose, path, particles, map -> its odom) and inputs."""

    def __init__(self, node, index: int, names: RobotNames, feed, initial_pose, diagnostics) -> None:
        self.view = RobotView(node, index, names, feed, initial_pose)
        self.diagnostics = RobotDiagnostics(diagnostics)
        self.outputs = self.view.outputs = Outputs(self.view, self.diagnostics, map_outputs=False)
        self.inputs = self.view.inputs = Inputs(self.view, self.outputs, self.diagnostics)
        # RViz's "2D Pose Estimate" for this robot, as AMCL under a robot namespace: <robot>/initialpose.
        self.initial_pose_sub = node.create_subscription(
            PoseWithCovarianceStamped, names.topic("initialpose"), lambda msg: set_pose_from(self.view, msg),
            QoSProfile(depth=1))

    @property
    def name(self) -> str:
        return self.view.names.robot

    def restart(self, feed) -> None:
        """A new fleet (the node's reset): feed it from now on."""
        self.view.slam = feed
        self.inputs.pipeline.restart(feed)
        self.outputs.reset()

    def apply_settings(self, settings) -> None:
        self.view.settings = self.view.names.settings(settings)
        self.outputs.path.resize(settings.path_max_length, settings.path_publish_max_poses)
        self.inputs.apply_settings(self.view.settings)

    def drops(self) -> Counter:
        """This robot's drops (node level, pipeline, filter), each under ``<robot>.<reason>``."""
        merged = Counter(self.view.drops)
        merged.update(self.inputs.pipeline.drops)
        merged.update(self.view.slam.filter().drops)
        return Counter({f"{self.name}.{reason}": count for reason, count in merged.items() if count})
