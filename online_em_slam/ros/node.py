"""ROS 2 node: landmark SLAM by particle online EM.

Inputs
  ``odom``                   nav_msgs/Odometry: motion input when motion_source = odom,
                             and always the odom -> base pose for map -> odom.
  ``control``                geometry_msgs/TwistStamped (motion_source = control):
                             linear.x speed, angular.z steering angle or yaw rate.
  ``landmark_observations``  sensor_msgs/PointCloud2 with fields range, bearing
                             [, id (-1 unknown), range_std, bearing_std].
Outputs
  ``~/pose`` ``~/path`` ``~/particles`` ``~/landmarks`` ``~/landmark_markers``,
  map -> odom (tf2_ros, else tf2_msgs/TFMessage on /tf, else ~/map_to_odom) and
  /diagnostics.  Services ``~/reset`` ``~/pause`` ``~/save_map`` ``~/load_map``.

Inputs take the path shared with the offline runner (:mod:`online_em_slam.pipeline`):
stamp checks (a lone bad stamp is dropped, a time jump needs confirmation), loss
detection, the stamp-ordered merge of the streams (``input_delay``) and the
feeder; so the node and ``online-em-slam run`` feed the estimator the identical
sequence.  Every input that cannot be used is dropped and counted by reason
(node counters merged with the path's and the core's), with a throttled
warning.  When the node cannot keep up with best-effort inputs it sheds
observation updates (``dropped.overload``), never motion; reliable inputs are
never shed (the publisher waits).  ``~/pose`` follows the odometry: each
odometry message gives the map-frame pose map->odom * odom->base at its stamp
(what a TF user computes), so the pose keeps flowing while the merge waits for a
slower stream; ``~/path`` is the estimator's pose after each observation message
(the offline runner's trajectory.csv).  Outputs carry the input stamps and are
checked finite before publishing.
"""
from __future__ import annotations

import bisect
import math
import os
import threading
import time
from collections import Counter, deque

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, TransformStamped, TwistStamped
from nav_msgs.msg import Odometry, Path
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType, JumpThreshold
from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ..core.models.angles import wrap_angle
from ..core.filter.slam import OnlineEMSlam
from ..pipeline import CONTROL, KIND_NAME, OBSERVATIONS, ODOMETRY, Fed, Feeder, InputPath, LoadMonitor
from ..core.mapping.mapfile import confined_path, map_file_path
from . import conversions as conv
from .initial_pose import pose_and_std

# Odometry positions beyond this (m) are absurd (the map's coordinate range, as initial_pose.*).
ODOMETRY_POSITION_LIMIT = 1e7
from .input_watch import InputWatch
from .path_history import PathHistory
from .tf import SensorFrames
from .params import ParameterError, build, current_values, declare_parameters


def input_qos(reliability: str, depth: int) -> QoSProfile:
    """Sensor inputs: best_effort (the default) matches every publisher, as REP-2003 and
    slam_toolbox do; reliable keeps every message (KEEP_ALL: a full queue makes a reliable
    publisher wait instead of losing), for lossless bag replay."""
    if reliability == "reliable":
        return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def latched_qos() -> QoSProfile:
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class _TransformSender:
    """map -> odom through the best available channel: tf2_ros, tf2_msgs on /tf, or ~/map_to_odom."""

    def __init__(self, node: Node) -> None:
        self.kind = "none"
        try:
            from tf2_ros import TransformBroadcaster  # noqa: PLC0415 (optional at run time)
            self._broadcaster = TransformBroadcaster(node)
            self.kind = "tf2_ros.TransformBroadcaster on /tf"
            self._send = self._broadcaster.sendTransform
            return
        except ImportError:
            pass
        try:
            from tf2_msgs.msg import TFMessage  # noqa: PLC0415
            publisher = node.create_publisher(TFMessage, "/tf", QoSProfile(depth=100))
            self.kind = "tf2_msgs/TFMessage on /tf"
            self._send = lambda t: publisher.publish(TFMessage(transforms=[t]))
            return
        except ImportError:
            pass
        publisher = node.create_publisher(TransformStamped, "~/map_to_odom", QoSProfile(depth=10))
        self.kind = "geometry_msgs/TransformStamped on ~/map_to_odom (tf2_ros and tf2_msgs not importable)"
        self._send = publisher.publish

    def send(self, transform: TransformStamped) -> None:
        self._send(transform)


class OnlineEmSlamNode(Node):
    """Particle online EM landmark SLAM as a ROS 2 node (see module docstring)."""

    def __init__(self, node_name: str = "online_em_slam", **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        declare_parameters(self)
        try:
            self._config, self._settings = build(current_values(self))
        except ParameterError as error:
            raise ParameterError(f"invalid parameter: {error}") from None
        s = self._settings
        self._lock = threading.RLock()
        self._slam = OnlineEMSlam(self._config, initial_pose=s.initial_pose)
        self._pending_config = None
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)

        # Input path (shared with the offline runner) and time bookkeeping.
        self._motion_kind = ODOMETRY if s.motion_source == "odom" else CONTROL
        self._inputs_path = InputPath((self._motion_kind, OBSERVATIONS), s.input_delay, s.time_jump_threshold,
                                      restart_on_jump_back=s.reset_on_time_jump)
        self._feeder = Feeder(self._slam, s.motion_source, self._inputs_path.drops)
        self._load = LoadMonitor()
        self.max_load = 0.0
        self._pending_jump = False
        self._paused = False

        self._init_outputs_and_statistics(s)
        self._create_topics(s)

        # Services.
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self.create_service(SetBool, "~/pause", self._srv_pause)
        self.create_service(Trigger, "~/save_map", self._srv_save_map)
        self.create_service(Trigger, "~/load_map", self._srv_load_map)

        self._create_timers(s)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        if s.load_map_on_start:
            self._log_result(*self._load_map())
        self.get_logger().info(
            f"online EM SLAM: motion_source={s.motion_source} (model {self._config.motion.model}), "
            f"{self._config.filter.num_particles} particles, EM {self._config.em.algorithm}; "
            f"map -> odom via {self._tf.kind}" + ("" if s.publish_tf else " (publish_tf is false)")
            + f"; sensor pose from {'TF, else ' if self._frames.uses_tf else ''}sensor.offset_*")

    # ------------------------------------------------------------------ helpers
    def _init_outputs_and_statistics(self, s) -> None:
        # Output state.
        self._odom_history: deque = deque(maxlen=400)
        self._map_to_odom: np.ndarray | None = None
        self._pose_covariance: np.ndarray | None = None
        self._pose_covariance_36 = None
        self._last_pose_stamp = -math.inf
        self._last_tf_ns = -1
        self._path = PathHistory(s.path_max_length, s.path_publish_max_poses)
        self._corrected: Counter = Counter()       # inputs used after a repair (normalised quaternions)
        self._frames = SensorFrames(self)          # frame ids checked; the sensor pose from TF (tf2_ros)
        self._watch = InputWatch()                 # silent input streams turn diagnostics WARN
        self._map_dirty = True

        # Statistics.
        self._drops: Counter = Counter()
        self._core_drops_carry: Counter = Counter()
        self._updates = self._inputs = 0
        self._window_start = time.monotonic()
        self._window_updates = self._window_inputs = 0
        self._latencies: list[float] = []
        self._last_ess = float("nan")
        self._resets = 0
        self._drops_reported = 0

    def _create_topics(self, s) -> None:
        """Publishers of the outputs, subscriptions of the inputs."""
        # Publishers.
        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, "~/pose", latched_qos())
        self._path_pub = self.create_publisher(Path, "~/path", latched_qos())
        self._particles_pub = self.create_publisher(PoseArray, "~/particles", QoSProfile(depth=5))
        self._landmarks_pub = self.create_publisher(PointCloud2, "~/landmarks", latched_qos())
        self._markers_pub = self.create_publisher(MarkerArray, "~/landmark_markers", latched_qos())
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", QoSProfile(depth=10))
        self._tf = _TransformSender(self)

        # Subscriptions.
        qos = input_qos(s.input_reliability, s.input_depth)
        self._odom_sub = self.create_subscription(Odometry, s.odom_topic, self._on_odom, qos,
                                                  event_callbacks=self._events(s.odom_topic))
        self._control_sub = None
        if s.motion_source == "control":
            self._control_sub = self.create_subscription(TwistStamped, s.control_topic, self._on_control,
                                                         qos, event_callbacks=self._events(s.control_topic))
        self._obs_sub = self.create_subscription(PointCloud2, s.observations_topic, self._on_observations,
                                                 qos, event_callbacks=self._events(s.observations_topic))
        # RViz's "2D Pose Estimate" and AMCL users publish here; remap to move it.
        self._initial_pose_sub = self.create_subscription(PoseWithCovarianceStamped, "/initialpose",
                                                          self._on_initial_pose, QoSProfile(depth=1))

    def _create_timers(self, s) -> None:
        # Timers run on the steady clock: they rate-limit work, independent of sim time.
        self._housekeeping_timer = self.create_timer(0.1, self._housekeeping, clock=self._steady)
        self._map_timer = self.create_timer(s.map_publish_period, self._publish_map, clock=self._steady)
        self._diag_timer = self.create_timer(s.diagnostics_period, self._publish_diagnostics,
                                             clock=self._steady)
        self._tf_timer = None
        if s.transform_publish_period > 0:
            self._tf_timer = self.create_timer(s.transform_publish_period, self._republish_transform,
                                               clock=self._steady)

        # Reset on a backward jump of the ROS clock (bag played in a loop).
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(seconds=-s.time_jump_threshold),
                          on_clock_change=False),
            post_callback=self._on_clock_jump)

    def _events(self, topic: str) -> SubscriptionEventCallbacks:
        def incompatible(info) -> None:
            self.get_logger().error(
                f"publisher on {topic!r} has an incompatible QoS (policy {info.last_policy_kind}); "
                "for best-effort publishers set input_qos.reliability: best_effort (the default)",
                throttle_duration_sec=self._settings.warn_throttle_period)

        def lost(info) -> None:
            with self._lock:
                self._drops["message_lost"] += int(info.total_count_change)
        return SubscriptionEventCallbacks(incompatible_qos=incompatible, message_lost=lost)

    def _now_sec(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _header(self, stamp: float | None, frame: str) -> Header:
        return Header(stamp=conv.sec_to_stamp(stamp if stamp is not None else self._now_sec()), frame_id=frame)

    def _log_result(self, ok: bool, message: str) -> None:
        if ok:
            self.get_logger().info(message)
        else:
            self.get_logger().error(message)

    def _drop(self, reason: str, count: int = 1) -> None:
        self._drops[reason] += count

    def all_drops(self) -> dict[str, int]:
        """Node-level drop counters merged with the core's, by reason."""
        with self._lock:
            merged = Counter(self._drops)
            merged.update(self._inputs_path.drops)
            merged.update(self._core_drops_carry)
            merged.update(self._slam.drops)
            return {k: int(v) for k, v in merged.items() if v}

    @property
    def slam(self) -> OnlineEMSlam:
        return self._slam

    @property
    def inputs_received(self) -> int:
        """Well-formed inputs received (processed, queued or dropped after decoding)."""
        return self._inputs

    @property
    def paused(self) -> bool:
        return self._paused

    # ------------------------------------------------------------------ input callbacks
    # Each callback decodes its message and hands it to the input path; every message
    # with a readable stamp tells the path its stream is alive, used or not.
    def _on_odom(self, msg: Odometry) -> None:
        started = time.monotonic()
        self._watch.heard(self._settings.odom_topic, started)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        yaw, quaternion_problem = conv.odometry_yaw(q)
        pose = np.array([p.x, p.y, yaw], dtype=float)
        with self._lock:
            self._frames.check_odometry(msg.child_frame_id, self._settings, msg.header.frame_id)
            if quaternion_problem == "degenerate_quaternion":
                self._refuse(ODOMETRY, stamp, quaternion_problem, "odometry with a degenerate (zero or "
                             f"yaw-less) orientation quaternion ({q.x}, {q.y}, {q.z}, {q.w})", started)
                return
            if not np.all(np.isfinite(pose)) or not np.isfinite([q.x, q.y, q.z, q.w]).all():
                self._refuse(ODOMETRY, stamp, "non_finite_odometry", "odometry with non-finite pose", started)
                return
            if np.max(np.abs(pose[:2])) > ODOMETRY_POSITION_LIMIT:
                # Finite but absurd: it would be published as ~/pose and spoil map -> odom.
                self._refuse(ODOMETRY, stamp, "implausible_odometry",
                             f"odometry at ({p.x:.3g}, {p.y:.3g}) m, beyond +-{ODOMETRY_POSITION_LIMIT:.0e} m", started)
                return
            if quaternion_problem:                   # used after normalisation: counted, not dropped
                self._corrected[quaternion_problem] += 1
            # A lone bad stamp (0, far future) must not stamp ~/pose or map -> odom: one
            # pose at 2^31 s would hold back every later one.
            on_time_line = self._inputs_path.on_time_line(ODOMETRY, stamp)
            if on_time_line:
                self._remember_odometry(stamp, pose)
            if self._motion_kind == ODOMETRY:
                self._input(ODOMETRY, stamp, pose, started)
            else:
                self._inputs += 1            # odometry only places map -> odom and ~/pose
                self._window_inputs += 1
                if on_time_line:
                    self._inputs_path.watch(ODOMETRY, stamp)
                else:
                    self._drop("stamp_outlier")
            if on_time_line:
                self._publish_odometry_pose(stamp, pose)
            self._load.add(time.monotonic(), time.monotonic() - started)

    def _on_control(self, msg: TwistStamped) -> None:
        started = time.monotonic()
        self._watch.heard(self._settings.control_topic, started)
        control = np.array([msg.twist.linear.x, msg.twist.angular.z], dtype=float)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        with self._lock:
            if stamp == 0.0:
                stamp = self._now_sec()      # unstamped twist: use the arrival time
            if not np.all(np.isfinite(control)):
                self._refuse(CONTROL, stamp, "non_finite_control", "control with non-finite speed or angle",
                             started)
                return
            self._input(CONTROL, stamp, control, started)
            self._load.add(time.monotonic(), time.monotonic() - started)

    def _on_observations(self, msg: PointCloud2) -> None:
        started = time.monotonic()
        self._watch.heard(self._settings.observations_topic, started)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        with self._lock:
            try:
                # Observations with invalid ids, zero ranges or wild bearings are left out and counted.
                observations = conv.observations_from_cloud(msg, drops=self._drops)
            except ValueError as error:      # CloudFormatError is a ValueError
                self._refuse(OBSERVATIONS, stamp, "malformed_cloud", f"malformed observation cloud: {error}",
                             started)
                return
            # Into the estimator's sensor frame: through TF when it resolves the cloud's frame.
            observations = self._frames.observations(msg.header.frame_id, stamp, observations, self._settings,
                                                     self._slam.config.sensor)
            # An empty cloud goes through the merge too: it says "nothing seen up to here".
            self._input(OBSERVATIONS, stamp, observations, started)
            self._load.add(time.monotonic(), time.monotonic() - started)

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Relocalise: the particles restart around the given pose, the map stays."""
        s = self._settings
        pose, std, problem = pose_and_std(msg, self._config.filter.initial_pose_std)
        with self._lock:
            if problem is not None:
                self._drop(problem)
                self.get_logger().warning(f"ignored /initialpose: {problem}")
                return
            if msg.header.frame_id not in ("", s.map_frame):
                self._drop("initial_pose_wrong_frame")
                self.get_logger().warning(f"ignored /initialpose in frame '{msg.header.frame_id}', "
                                          f"expected '{s.map_frame}'")
                return
            self._slam.set_pose(pose, std)
            self._feeder.rollback.checkpoint()       # a failing input later must not undo the new pose
            self.get_logger().info(f"pose set to ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.3f}) "
                                   f"from /initialpose; the map is kept")

    def _refuse(self, kind: int, stamp: float, reason: str, what: str, started: float) -> None:
        """An input whose payload is unusable: counted, and its stamp still advances its stream."""
        self._drop(reason)
        self.get_logger().warning(f"dropped {what}", throttle_duration_sec=self._settings.warn_throttle_period)
        if not self._paused and kind in (self._motion_kind, OBSERVATIONS):
            self._use(self._inputs_path.heard(kind, stamp, started))

    # ------------------------------------------------------------------ input path and estimator
    def _input(self, kind: int, stamp: float, payload, started: float) -> None:
        if kind != OBSERVATIONS or len(payload):
            self._inputs += 1
            self._window_inputs += 1
        if self._paused:
            self._drop("paused")
            return
        self._check_clock_jump()
        pushed = self._inputs_path.push(kind, stamp, payload, started)
        if pushed.restarted:
            jump = pushed.jump
            self._reset(f"{KIND_NAME[jump.released[0].kind]} stamps jumped back {jump.size:.3f} s "
                        f"(confirmed by {len(jump.released)} inputs)", keep_inputs=True, keep_map=True)
        elif pushed.jump is not None:
            self.get_logger().warning(f"input stamps jumped {'back' if pushed.jump.backward else 'ahead'} "
                                      f"{pushed.jump.size:.3f} s (confirmed by {len(pushed.jump.released)} inputs)")
        self._use(pushed.released)

    def _use(self, released: list) -> None:
        """Feed released inputs to the estimator in order; then publish once.

        After motion alone the estimate and the odometry move together: map -> odom
        keeps its value and ~/pose follows the odometry, so the estimate is read
        (a pose() costs a motion integration) only after an observation update, while
        map -> odom is not yet known, or when no odometry arrives to carry ~/pose.
        """
        if not released:
            return
        used = observed = False
        for item in released:
            try:
                fed = self._feed(item)
                used |= fed.moved or fed.report is not None
                observed |= fed.report is not None
                if fed.error is not None:       # counted by the feeder; the estimator is as before the input
                    self.get_logger().error(f"{KIND_NAME[item.kind]} at {item.stamp:.3f} failed and was dropped, "
                                            f"the estimate kept: {fed.error!r}",
                                            throttle_duration_sec=self._settings.warn_throttle_period)
            except Exception as error:  # noqa: BLE001 - bad input must never stop the node
                self._drop("internal_error")
                self.get_logger().error(f"failed to process {KIND_NAME[item.kind]} at {item.stamp:.3f}: {error!r}",
                                        throttle_duration_sec=self._settings.warn_throttle_period)
            self._latencies.append(time.monotonic() - item.wall)
        if observed or (used and (self._map_to_odom is None or not self._odometry_flows())):
            self._after_update()

    def _odometry_flows(self) -> bool:
        """Odometry arrived within the last second of estimator time (it then carries ~/pose)."""
        stamp = self._slam.last_stamp
        return bool(self._odom_history) and stamp is not None and self._odom_history[-1][0] >= stamp - 1.0

    def _feed(self, item) -> Fed:
        load = self._load.load(time.monotonic()) if item.kind == OBSERVATIONS else 0.0
        self.max_load = max(self.max_load, load)
        # Shedding keeps best-effort queues from overflowing; with reliable (KEEP_ALL) inputs
        # the publisher waits instead, so a lossless replay is never shed.
        shed = load > self._load.limit and self._settings.input_reliability != "reliable"
        fed = self._feeder.apply(item, use_observations=not shed)
        if fed.trajectory_point is not None:
            t, x, y, yaw = fed.trajectory_point
            self._path.append(t, (x, y, yaw))         # compact; messages are built at publish time
        report = fed.report
        if report is None:
            return fed
        if report.dropped:
            self.get_logger().warning("observations dropped by the estimator: "
                                      + ", ".join(f"{k}={v}" for k, v in sorted(report.dropped.items())),
                                      throttle_duration_sec=self._settings.warn_throttle_period)
        if math.isfinite(report.ess):
            self._last_ess = float(report.ess)
        self._updates += 1
        self._window_updates += 1
        self._map_dirty = True
        self._publish_particles()
        return fed

    # ------------------------------------------------------------------ outputs
    def _after_update(self) -> None:
        stamp = self._slam.last_stamp
        if stamp is None:
            return
        estimate = self._slam.pose()
        if not (np.all(np.isfinite(estimate.mean)) and np.all(np.isfinite(estimate.covariance))):
            self._drop("non_finite_estimate")
            self.get_logger().error("estimate is not finite; pose not published",
                                    throttle_duration_sec=self._settings.warn_throttle_period)
            return
        self._pose_covariance = estimate.covariance
        self._pose_covariance_36 = conv.pose_to_msg(Header(), estimate).pose.covariance   # reused per odometry
        if stamp > self._last_pose_stamp:
            self._publish_pose(stamp, estimate.mean)
        odom_pose = self._odom_at(stamp)
        if odom_pose is None and self._settings.publish_tf:
            self.get_logger().warning(
                f"no recent odometry on {self._settings.odom_topic!r} at {stamp:.3f} s: map -> odom not updated",
                throttle_duration_sec=30.0)
        if odom_pose is not None:
            map_to_odom = conv.pose2d_compose(estimate.mean, conv.pose2d_inverse(odom_pose))
            if np.all(np.isfinite(map_to_odom)):
                self._map_to_odom = map_to_odom
                self._send_transform(stamp)

    def _publish_pose(self, stamp: float, mean: np.ndarray) -> None:
        # Built by hand with the covariance of the last update: this runs at the odometry rate.
        if not np.all(np.isfinite(mean)):
            self._drop("non_finite_estimate")
            return
        msg = PoseWithCovarianceStamped(header=self._header(stamp, self._settings.map_frame))
        msg.pose.pose = conv.pose_msg(float(mean[0]), float(mean[1]), float(mean[2]))
        msg.pose.covariance = self._pose_covariance_36
        self._last_pose_stamp = stamp
        self._pose_pub.publish(msg)

    def _publish_odometry_pose(self, stamp: float, odom_pose: np.ndarray) -> None:
        """~/pose at an odometry stamp ahead of the estimator: map->odom * odom->base, as TF gives it."""
        if self._map_to_odom is None or self._pose_covariance is None or stamp <= self._last_pose_stamp:
            return
        self._publish_pose(stamp, conv.pose2d_compose(self._map_to_odom, odom_pose))

    def _remember_odometry(self, stamp: float, pose: np.ndarray) -> None:
        """Odometry history in stamp order (map -> odom is computed at estimator stamps)."""
        if not self._odom_history or stamp > self._odom_history[-1][0]:
            self._odom_history.append((stamp, pose))

    def _odom_at(self, stamp: float) -> np.ndarray | None:
        """Odometry pose at ``stamp``, interpolated from the recent odometry (None if too far)."""
        history = self._odom_history
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

    def _send_transform(self, data_stamp: float | None) -> None:
        s = self._settings
        if not s.publish_tf or self._map_to_odom is None:
            return
        base = max(data_stamp if data_stamp is not None else 0.0, self._now_sec())
        stamp_ns = int(round((base + s.transform_timeout) * 1e9))
        if stamp_ns <= self._last_tf_ns:
            return                                  # never the same stamp twice
        msg = conv.transform_msg(conv.sec_to_stamp(stamp_ns * 1e-9), s.map_frame, s.odom_frame,
                                 self._map_to_odom)
        if msg is None:
            return
        self._last_tf_ns = stamp_ns
        self._tf.send(msg)

    def _republish_transform(self) -> None:
        with self._lock:
            self._send_transform(self._slam.last_stamp)

    def _publish_particles(self) -> None:
        if not self._settings.publish_particles or self._slam.last_stamp is None:
            return
        poses, _ = self._slam.particles()
        self._particles_pub.publish(conv.particles_to_msg(self._header(self._slam.last_stamp,
                                                                       self._settings.map_frame), poses))

    def _publish_map(self) -> None:
        """Landmark cloud, markers and path; rate-limited by map_publish_period."""
        with self._lock:
            if not self._map_dirty:
                return
            self._map_dirty = False
            s = self._settings
            header = self._header(self._slam.last_stamp, s.map_frame)
            landmarks = self._slam.landmarks()
            cloud, skipped = conv.landmarks_to_cloud(header, landmarks)
            for reason, count in skipped.items():
                self._drop(reason, count)
            self._landmarks_pub.publish(cloud)
            self._markers_pub.publish(conv.landmarks_to_markers(header, landmarks, s.marker_sigma))
            if s.path_max_length > 0:
                self._path_pub.publish(self._path.to_msg(header))    # at most path_publish_max_poses

    def _publish_diagnostics(self) -> None:
        with self._lock:
            now = time.monotonic()
            span = max(now - self._window_start, 1e-6)
            latencies = np.asarray(self._latencies) if self._latencies else np.zeros(0)
            drops = self.all_drops()
            total = sum(drops.values())
            landmarks = self._slam.landmarks()
            values = {
                "update_rate_hz": self._window_updates / span,
                "input_rate_hz": self._window_inputs / span,
                "latency_mean_ms": 1e3 * float(latencies.mean()) if latencies.size else 0.0,
                "latency_max_ms": 1e3 * float(latencies.max()) if latencies.size else 0.0,
                "ess": self._last_ess if math.isfinite(self._last_ess) else float(self._config.filter.num_particles),
                "num_particles": self._slam.config.filter.num_particles,
                "landmarks": len(landmarks),
                "confirmed_landmarks": int(np.count_nonzero(landmarks.confirmed)),
                "observation_updates": self._updates,
                "inputs": self._inputs,
                "queued_inputs": len(self._inputs_path),
                "load": self._load.load(now),
                "load_max": self.max_load,
                "paused": self._paused,
                "resets": self._resets,
                "last_stamp": self._slam.last_stamp if self._slam.last_stamp is not None else -1.0,
                "dropped_total": total,
            }
            learned = self._slam.learned_noise()              # noise learned online (noise_learning.py)
            if learned["enabled"]:
                values.update({f"noise_learned.{k}": v for k, v in learned.items() if k not in ("enabled", "learning")})
            values.update({f"dropped.{reason}": count for reason, count in sorted(drops.items())})
            values.update({f"corrected.{reason}": count for reason, count in sorted(self._corrected.items())})
            values.update(self._frames.diagnostics())      # unexpected_frame.*, unexpected_child_frame.*
            level, message = DiagnosticStatus.OK, f"{len(landmarks)} landmarks"
            if self._paused:
                level, message = DiagnosticStatus.WARN, "paused"
            elif total > self._drops_reported:
                level = DiagnosticStatus.WARN
                message += f", {total - self._drops_reported} inputs dropped in the last {span:.1f} s"
            elif self._updates == 0:
                message = "waiting for observations"
            stale = self._watch.stale(time.monotonic(), self._settings.input_delay)
            if stale and not self._paused:
                level = DiagnosticStatus.WARN
                message += "; silent inputs: " + ", ".join(f"{name} for {age:.1f} s" for name, age in stale)
            self._drops_reported = total
            self._window_start, self._window_updates, self._window_inputs = now, 0, 0
            self._latencies = []
            stamp = self._now_sec()
            if stamp <= 0.0 and self._slam.last_stamp is not None:
                stamp = self._slam.last_stamp
            status = DiagnosticStatus(
                level=level, name=f"{self.get_name()}: online EM SLAM", message=message,
                hardware_id=self.get_fully_qualified_name(),
                values=[KeyValue(key=k, value=(f"{v:.6g}" if isinstance(v, float) else str(v)))
                        for k, v in values.items()])
            self._diag_pub.publish(DiagnosticArray(header=Header(stamp=conv.sec_to_stamp(stamp)),
                                                   status=[status]))

    # ------------------------------------------------------------------ time
    def _on_clock_jump(self, jump) -> None:
        # Runs inside the clock update: only note it; the reset happens in _check_clock_jump.
        self._pending_jump = True

    def _check_clock_jump(self) -> None:
        """A /clock jump back confirms a time jump by itself (bag played in a loop)."""
        if not self._pending_jump:
            return
        self._pending_jump = False
        s = self._settings
        now = self._now_sec()
        newest = self._inputs_path.newest
        if s.reset_on_time_jump and newest is not None and newest > now + s.time_jump_threshold:
            self._reset(f"clock jumped back to {now:.3f} s", keep_map=True)

    def _housekeeping(self) -> None:
        with self._lock:
            self._check_clock_jump()
            # A stream that went silent stops holding the others back.
            self._use(self._inputs_path.release(time.monotonic()))

    def _reset(self, reason: str, keep_inputs: bool = False, keep_map: bool = False) -> None:
        """Restart the estimate; ``keep_inputs``: the input path already restarted on a confirmed jump;
        ``keep_map`` (a time jump, not asked by the user): only the pose and the time line restart."""
        with self._lock:
            s = self._settings
            if keep_map:                 # as robot_localization and AMCL, the state survives a time jump
                self._slam.restart_time_line(s.initial_pose)
            elif self._pending_config is not None:
                self._core_drops_carry.update(self._slam.drops)
                self._config = self._pending_config
                self._pending_config = None
                self._slam = OnlineEMSlam(self._config, initial_pose=s.initial_pose)
            else:
                self._slam.reset(initial_pose=s.initial_pose, stamp=None)
            if not keep_inputs:
                self._inputs_path.reset()
            self._feeder.reset(self._slam)
            self._odom_history.clear()
            self._map_to_odom = None
            self._pose_covariance = None
            self._last_pose_stamp = -math.inf
            self._last_tf_ns = -1
            self._path.clear()
            self._map_dirty = True
            self._last_ess = float("nan")
            self._resets += 1
            self.get_logger().warning(f"estimate reset: {reason}" + ("; the map is kept" if keep_map else ""))

    # ------------------------------------------------------------------ services
    def _srv_reset(self, request, response):
        self._reset("reset service")
        response.success, response.message = True, "estimate and map reset"
        return response

    def _srv_pause(self, request, response):
        with self._lock:
            self._paused = bool(request.data)
            self._inputs_path.forget_time_line()     # the stamps after a pause continue elsewhere
        response.success = True
        response.message = "paused: inputs are ignored" if self._paused else "resumed"
        self.get_logger().info(response.message)
        return response

    def _map_directory(self) -> str:
        return map_file_path(self._settings.map_file, self._settings.map_directory)[1]

    def _map_path(self) -> str:
        """map_file resolved inside map_directory (MapFileError if it escapes: '..', symlinks)."""
        return confined_path(*map_file_path(self._settings.map_file, self._settings.map_directory))

    def _srv_save_map(self, request, response):
        with self._lock:
            try:
                path = self._map_path()
                # Only the configured directory (never its parents) and directories inside
                # it are created; the path is resolved again once they exist.
                root = os.path.realpath(self._map_directory())
                if not os.path.isdir(root):
                    os.mkdir(root)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                path = self._map_path()
                self._slam.save_map(path)    # validated, fsynced temporary file + rename (core/mapping/mapfile.py)
                response.success = True
                response.message = f"saved {len(self._slam.landmarks())} landmarks to {path}"
            except Exception as error:  # noqa: BLE001 - a failed save must never stop the node
                response.success, response.message = False, f"could not save map: {error}"
        self._log_result(response.success, response.message)
        return response

    def _load_map(self) -> tuple[bool, str]:
        with self._lock:
            try:
                path = self._map_path()
                self._slam.load_map(path)    # validated completely first; unchanged on failure
            except Exception as error:  # noqa: BLE001
                return False, f"could not load map: {error}"
            self._feeder.rollback.checkpoint()
            self._map_dirty = True
            self._path.clear()
        self._publish_map()
        return True, f"loaded {len(self._slam.landmarks())} landmarks from {path}"

    def _srv_load_map(self, request, response):
        response.success, response.message = self._load_map()
        self._log_result(response.success, response.message)
        return response

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        values = current_values(self)
        values.update({p.name: p.value for p in parameters})
        try:
            build(values)
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, parameters) -> None:
        try:
            config, settings = build(current_values(self))
        except ParameterError as error:      # cannot happen: checked in _on_set_parameters
            self.get_logger().error(f"parameters not applied: {error}")
            return
        with self._lock:
            self._path.resize(settings.path_max_length, settings.path_publish_max_poses)
            self._settings = settings
            self._inputs_path.sequencer.silence = settings.input_delay
            if config != self._slam.config:
                self._pending_config = config
                self.get_logger().info("core settings changed; they take effect at the next reset (~/reset)")
            else:
                self._pending_config = None


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = OnlineEmSlamNode()
        rclpy.spin(node)
    except ParameterError as error:
        rclpy.logging.get_logger("online_em_slam").fatal(str(error))
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    raise SystemExit(main())
