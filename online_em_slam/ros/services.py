"""The node's user commands: services ``~/reset``, ``~/pause``, and relocalisation
from ``initialpose`` (the map-file services are in ``map_files.py``).

``initialpose`` (RViz's "2D Pose Estimate", AMCL's topic) restarts the
particles around the given pose and keeps the map.
"""
from __future__ import annotations

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.qos import QoSProfile
from std_srvs.srv import SetBool, Trigger

from .initial_pose import pose_and_std


class Commands:
    """Services and /initialpose (``node``: OnlineEmSlamNode); they act on the node under its lock."""

    def __init__(self, node) -> None:
        self.node = node
        # RViz's "2D Pose Estimate" and AMCL users publish here: `initialpose` in the node's
        # namespace, as AMCL (/initialpose without one, /robot1/initialpose under robot1).
        # Fleet mode: one per robot, <robot>/initialpose (fleet_robot.py).
        self.initial_pose_sub = None if node.fleet_mode else node.create_subscription(
            PoseWithCovarianceStamped, "initialpose", self.on_initial_pose, QoSProfile(depth=1))
        node.create_service(Trigger, "~/reset", self.reset)
        node.create_service(SetBool, "~/pause", self.pause)

    # ------------------------------------------------------------------ estimate
    def reset(self, request, response):
        self.node.reset("reset service")
        response.success, response.message = True, "estimate and map reset"
        return response

    def pause(self, request, response):
        node = self.node
        with node.lock:
            node.paused = bool(request.data)
            node.inputs.pipeline.forget_time_line()     # the stamps after a pause continue elsewhere
        response.success = True
        response.message = "paused: inputs are ignored" if node.paused else "resumed"
        node.get_logger().info(response.message)
        return response

    def on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        set_pose_from(self.node, msg)


def set_pose_from(node, msg: PoseWithCovarianceStamped) -> None:
    """Relocalise ``node``'s estimate (the node, or one robot's view of it in fleet mode):
    the particles restart around the given pose, the map stays."""
    s = node.settings
    pose, std, problem = pose_and_std(msg, node.config.filter.initial_pose_std)
    with node.lock:
        if problem is not None:
            node.drops[problem] += 1
            node.get_logger().warning(f"ignored initialpose: {problem}")
            return
        if msg.header.frame_id not in ("", s.map_frame):
            node.drops["initial_pose_wrong_frame"] += 1
            node.get_logger().warning(f"ignored initialpose in frame '{msg.header.frame_id}', "
                                      f"expected '{s.map_frame}'")
            return
        node.slam.set_pose(pose, std)
        node.inputs.pipeline.checkpoint()       # a failing input later must not undo the new pose
        node.get_logger().info(f"pose set to ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.3f}) "
                               f"from initialpose; the map is kept")
