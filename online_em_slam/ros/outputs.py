"""The node's outputs: ``~/pose``, ``~/path``, ``~/particles``, ``~/landmarks``,
``~/landmark_markers`` and map -> odom.

``~/pose`` follows the odometry: each odometry message gives the map-frame pose
map->odom * odom->base at its stamp (what a TF user computes), so the pose keeps
flowing while the merge waits for a slower stream; ``~/path`` is the
estimator's pose after each observation message (the offline runner's
trajectory.csv).  The input pipeline calls :meth:`Outputs.applied` for every
input it applied and :meth:`Outputs.settled` after each batch.  Outputs carry the
input stamps and are checked finite before publishing.
"""
from __future__ import annotations

import bisect
import math
import time
from collections import deque

import numpy as np
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import Path
from rclpy.qos import QoSProfile
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from ..core.models.angles import wrap_angle
from ..core.types import split_decisions
from ..pipeline import KIND_NAME
from . import conversions as conv
from .path_history import PathHistory
from .qos import latched_qos
from .transform_sender import TransformSender


class Outputs:
    """Publishers, map -> odom and the state they are computed from (``node``: OnlineEmSlamNode)."""

    def __init__(self, node, diagnostics, robot_outputs: bool = True, map_outputs: bool = True) -> None:
        """``robot_outputs``: ~/pose, ~/path, ~/particles and map -> odom; ``map_outputs``: ~/landmarks
        and ~/landmark_markers (fleet mode: each robot's Outputs has the first, the node's the second)."""
        self.node = node
        self.diagnostics = diagnostics
        s = node.settings
        self.odom_history: deque = deque(maxlen=400)
        self.map_to_odom: np.ndarray | None = None
        self.pose_covariance: np.ndarray | None = None
        self.pose_covariance_36 = None
        self.last_pose_stamp = -math.inf
        self.last_tf_ns = -1
        self.path = PathHistory(s.path_max_length, s.path_publish_max_poses)
        self.revised = None             # the estimator's revised trajectory the path holds
        self.map_dirty = True
        self.pose_pub = self.path_pub = self.particles_pub = self.landmarks_pub = self.markers_pub = None
        self.transform = None
        if robot_outputs:
            self.pose_pub = node.create_publisher(PoseWithCovarianceStamped, "~/pose", latched_qos())
            self.path_pub = node.create_publisher(Path, "~/path", latched_qos())
            self.particles_pub = node.create_publisher(PoseArray, "~/particles", QoSProfile(depth=5))
        if map_outputs:
            self.landmarks_pub = node.create_publisher(PointCloud2, "~/landmarks", latched_qos())
            self.markers_pub = node.create_publisher(MarkerArray, "~/landmark_markers", latched_qos())
        if robot_outputs:
            self.transform = TransformSender(node)

    def reset(self) -> None:
        """Forget the estimate-derived state (an estimate reset)."""
        self.odom_history.clear()
        self.map_to_odom = None
        self.pose_covariance = None
        self.last_pose_stamp = -math.inf
        self.last_tf_ns = -1
        self.path.clear()
        self.revised = None
        self.map_dirty = True

    # ------------------------------------------------------------------ from the input pipeline
    def applied(self, item, fed) -> None:
        """One input the pipeline applied: the path, the particles and the update statistics."""
        node = self.node
        try:
            self._record(fed)
            if fed.error is not None:       # counted by the feeder; the estimator is as before the input
                node.throttle.error("input_failed", f"{KIND_NAME[item.kind]} at {item.stamp:.3f} failed and was "
                                    f"dropped, the estimate kept: {fed.error!r}")
        except Exception as error:  # noqa: BLE001 - bad input must never stop the node
            node.drops["internal_error"] += 1
            node.throttle.error("output_failed",
                                f"failed to process {KIND_NAME[item.kind]} at {item.stamp:.3f}: {error!r}")
        self.diagnostics.latency(time.monotonic() - item.wall)

    def _record(self, fed) -> None:
        if fed.trajectory_point is not None:
            t, x, y, yaw = fed.trajectory_point
            self.path.append(t, (x, y, yaw))         # compact; messages are built at publish time
        report = fed.report
        if report is None:
            return
        self._revise_path()
        dropped, _ = split_decisions(report.dropped)          # decisions are no fault: not warned about
        if dropped:
            self.node.throttle.warning("estimator_drops", "observations dropped by the estimator: "
                                       + ", ".join(f"{k}={v}" for k, v in sorted(dropped.items())))
        self.diagnostics.updated(report)
        self.map_dirty = True
        self.publish_particles()

    def _revise_path(self) -> None:
        """A replay that took over filtered the past again: its poses replace the path's up to then."""
        revised = getattr(self.node.slam, "revised_trajectory", lambda: None)()
        if revised is not None and revised is not self.revised:
            self.revised = revised
            self.path.revise(revised)
            self.map_dirty = True

    def settled(self, used: bool, observed: bool) -> None:
        """After a batch of applied inputs: publish once.

        After motion alone the estimate and the odometry move together: map -> odom
        keeps its value and ~/pose follows the odometry, so the estimate is read
        (a pose() costs a motion integration) only after an observation update, while
        map -> odom is not yet known, or when no odometry arrives to carry ~/pose.
        """
        if observed or (used and (self.map_to_odom is None or not self._odometry_flows())):
            self.after_update()

    def _odometry_flows(self) -> bool:
        """Odometry arrived within the last second of estimator time (it then carries ~/pose)."""
        stamp = self.node.slam.last_stamp
        return bool(self.odom_history) and stamp is not None and self.odom_history[-1][0] >= stamp - 1.0

    def after_update(self) -> None:
        """~/pose and map -> odom from the estimate."""
        node, s = self.node, self.node.settings
        slam = node.slam
        stamp = slam.last_stamp
        if stamp is None:
            return
        estimate = slam.pose()
        if not (np.all(np.isfinite(estimate.mean)) and np.all(np.isfinite(estimate.covariance))):
            node.drops["non_finite_estimate"] += 1
            node.throttle.error("non_finite_estimate", "estimate is not finite; pose not published")
            return
        self.pose_covariance = estimate.covariance
        self.pose_covariance_36 = conv.pose_to_msg(Header(), estimate).pose.covariance   # reused per odometry
        if stamp > self.last_pose_stamp:
            self._publish_pose(stamp, estimate.mean)
        odom_pose = self.odom_at(stamp)
        if odom_pose is None and s.publish_tf:
            node.throttle.warning("no_recent_odometry", f"no recent odometry on {s.odom_topic!r} at {stamp:.3f} s: "
                                  "map -> odom not updated", period=30.0)
        if odom_pose is not None:
            map_to_odom = conv.pose2d_compose(estimate.mean, conv.pose2d_inverse(odom_pose))
            if np.all(np.isfinite(map_to_odom)):
                self.map_to_odom = map_to_odom
                self.send_transform(stamp)

    # ------------------------------------------------------------------ pose and odometry
    def _publish_pose(self, stamp: float, mean: np.ndarray) -> None:
        # Built by hand with the covariance of the last update: this runs at the odometry rate.
        if not np.all(np.isfinite(mean)):
            self.node.drops["non_finite_estimate"] += 1
            return
        msg = PoseWithCovarianceStamped(header=self.node.header(stamp, self.node.settings.map_frame))
        msg.pose.pose = conv.pose_msg(float(mean[0]), float(mean[1]), float(mean[2]))
        msg.pose.covariance = self.pose_covariance_36
        self.last_pose_stamp = stamp
        self.pose_pub.publish(msg)

    def publish_odometry_pose(self, stamp: float, odom_pose: np.ndarray) -> None:
        """~/pose at an odometry stamp ahead of the estimator: map->odom * odom->base, as TF gives it."""
        if self.map_to_odom is None or self.pose_covariance is None or stamp <= self.last_pose_stamp:
            return
        self._publish_pose(stamp, conv.pose2d_compose(self.map_to_odom, odom_pose))

    def remember_odometry(self, stamp: float, pose: np.ndarray) -> None:
        """Odometry history in stamp order (map -> odom is computed at estimator stamps)."""
        if not self.odom_history or stamp > self.odom_history[-1][0]:
            self.odom_history.append((stamp, pose))

    def odom_at(self, stamp: float) -> np.ndarray | None:
        """Odometry pose at ``stamp``, interpolated from the recent odometry (None if too far)."""
        history = self.odom_history
        if not history:
            return None
        if stamp >= history[-1][0]:
            return history[-1][1] if stamp - history[-1][0] <= 1.0 else None
        if stamp <= history[0][0]:
            return history[0][1] if history[0][0] - stamp <= 1.0 else None
        # History is in stamp order: bisect instead of scanning it on every update.
        k = bisect.bisect_right(history, stamp, key=lambda item: item[0])
        (t0, p0), (t1, p1) = history[k - 1], history[k]
        a = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
        out = p0 + a * (p1 - p0)
        out[2] = wrap_angle(p0[2] + a * wrap_angle(p1[2] - p0[2]))
        return out

    # ------------------------------------------------------------------ map -> odom
    def send_transform(self, data_stamp: float | None) -> None:
        s = self.node.settings
        if not s.publish_tf or self.map_to_odom is None or self.transform is None:
            return
        base = max(data_stamp if data_stamp is not None else 0.0, self.node.now_sec())
        stamp_ns = int(round((base + s.transform_timeout) * 1e9))
        if stamp_ns <= self.last_tf_ns:
            return                                  # never the same stamp twice
        msg = conv.transform_msg(conv.sec_to_stamp(stamp_ns * 1e-9), s.map_frame, s.odom_frame,
                                 self.map_to_odom)
        if msg is None:
            return
        self.last_tf_ns = stamp_ns
        self.transform.send(msg)

    def republish_transform(self) -> None:
        """map -> odom again (timer, transform_publish_period)."""
        with self.node.lock:
            self.send_transform(self.node.slam.last_stamp)

    # ------------------------------------------------------------------ particles and map
    def publish_particles(self) -> None:
        slam, s = self.node.slam, self.node.settings
        if not s.publish_particles or slam.last_stamp is None:
            return
        poses, _ = slam.particles()
        self.particles_pub.publish(conv.particles_to_msg(self.node.header(slam.last_stamp, s.map_frame), poses))

    def publish_map(self) -> None:
        """Landmark cloud, markers and path; rate-limited by map_publish_period.

        The cloud and the markers hold the confirmed landmarks only: a tentative one
        is a candidate (association.confirm_observations), and one scan of clutter
        would otherwise be published as the map until it is pruned."""
        node = self.node
        with node.lock:
            if not self.map_dirty:
                return
            self.map_dirty = False
            s = node.settings
            header = node.header(node.slam.last_stamp, s.map_frame)
            if self.landmarks_pub is not None:
                landmarks = node.slam.landmarks(confirmed_only=True)  # the map: tentative rows are candidates
                cloud, skipped = conv.landmarks_to_cloud(header, landmarks)
                for reason, count in skipped.items():
                    node.drops[reason] += count
                self.landmarks_pub.publish(cloud)
                self.markers_pub.publish(conv.landmarks_to_markers(header, landmarks, s.marker_sigma))
            if s.path_max_length > 0 and self.path_pub is not None:
                self.path_pub.publish(self.path.to_msg(header))    # at most path_publish_max_poses
