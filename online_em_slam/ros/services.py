"""The node's user commands: services ``~/reset``, ``~/pause``, ``~/save_map``,
``~/load_map``, and relocalisation from ``/initialpose``.

``/initialpose`` (RViz's "2D Pose Estimate", AMCL's topic) restarts the
particles around the given pose and keeps the map.  Maps are saved and loaded
only inside ``map_directory`` (``map_file`` is resolved there; '..' and
symlinks out of it are refused).
"""
from __future__ import annotations

import os

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.qos import QoSProfile
from std_srvs.srv import SetBool, Trigger

from ..core.mapping.mapfile import confined_path, map_file_path
from .initial_pose import pose_and_std


class Commands:
    """Services and /initialpose (``node``: OnlineEmSlamNode); they act on the node under its lock."""

    def __init__(self, node) -> None:
        self.node = node
        # RViz's "2D Pose Estimate" and AMCL users publish here: `initialpose` in the node's
        # namespace, as AMCL (/initialpose without one, /robot1/initialpose under robot1).
        self.initial_pose_sub = node.create_subscription(PoseWithCovarianceStamped, "initialpose",
                                                         self.on_initial_pose, QoSProfile(depth=1))
        node.create_service(Trigger, "~/reset", self.reset)
        node.create_service(SetBool, "~/pause", self.pause)
        node.create_service(Trigger, "~/save_map", self.save_map)
        node.create_service(Trigger, "~/load_map", self.load_map)

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
        """Relocalise: the particles restart around the given pose, the map stays."""
        node = self.node
        s = node.settings
        pose, std, problem = pose_and_std(msg, node.config.filter.initial_pose_std)
        with node.lock:
            if problem is not None:
                node.drops[problem] += 1
                node.get_logger().warning(f"ignored /initialpose: {problem}")
                return
            if msg.header.frame_id not in ("", s.map_frame):
                node.drops["initial_pose_wrong_frame"] += 1
                node.get_logger().warning(f"ignored /initialpose in frame '{msg.header.frame_id}', "
                                          f"expected '{s.map_frame}'")
                return
            node.slam.set_pose(pose, std)
            node.inputs.pipeline.checkpoint()       # a failing input later must not undo the new pose
            node.get_logger().info(f"pose set to ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.3f}) "
                                   f"from /initialpose; the map is kept")

    # ------------------------------------------------------------------ map files
    def _map_directory(self) -> str:
        s = self.node.settings
        return map_file_path(s.map_file, s.map_directory)[1]

    def _map_path(self) -> str:
        """map_file resolved inside map_directory (MapFileError if it escapes: '..', symlinks)."""
        s = self.node.settings
        return confined_path(*map_file_path(s.map_file, s.map_directory))

    def save_map(self, request, response):
        node = self.node
        with node.lock:
            try:
                path = self._map_path()
                # Only the configured directory (never its parents) and directories inside
                # it are created; the path is resolved again once they exist.
                root = os.path.realpath(self._map_directory())
                if not os.path.isdir(root):
                    os.mkdir(root)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                path = self._map_path()
                node.slam.save_map(path)    # validated, fsynced temporary file + rename (core/mapping/mapfile.py)
                response.success = True
                response.message = f"saved {len(node.slam.landmarks())} landmarks to {path}"
            except Exception as error:  # noqa: BLE001 - a failed save must never stop the node
                response.success, response.message = False, f"could not save map: {error}"
        node.log_result(response.success, response.message)
        return response

    def load(self) -> tuple[bool, str]:
        """Load map_file into the estimator: (success, message)."""
        node = self.node
        with node.lock:
            try:
                path = self._map_path()
                node.slam.load_map(path)    # validated completely first; unchanged on failure
            except Exception as error:  # noqa: BLE001
                return False, f"could not load map: {error}"
            node.inputs.pipeline.checkpoint()
            node.outputs.map_dirty = True
            node.outputs.path.clear()
        node.outputs.publish_map()
        return True, f"loaded {len(node.slam.landmarks())} landmarks from {path}"

    def load_map(self, request, response):
        response.success, response.message = self.load()
        self.node.log_result(response.success, response.message)
        return response
