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

Inputs go through a small buffer ordered by stamp (``input_delay``); every
input that cannot be used is dropped and counted by reason (node counters
merged with the core's ``drops``), with a throttled warning.  Outputs carry
the input stamps and are checked finite before publishing.
"""
from __future__ import annotations

import bisect
import heapq
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

from ..core.angles import wrap_angle
from ..core.slam import OnlineEMSlam
from ..core.mapfile import confined_path
from . import conversions as conv
from .path_history import PathHistory
from .params import ParameterError, build, current_values, declare_parameters

ODOM, OBSERVATIONS, CONTROL = 0, 1, 2      # processing order of inputs with equal stamps
_KIND_NAME = {ODOM: "odometry", OBSERVATIONS: "observations", CONTROL: "control"}


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

        # Input buffer and time bookkeeping.
        self._buffer: list = []
        self._seq = 0
        self._newest: float | None = None
        self._newest_by_kind: dict[int, float] = {}
        self._stream_wall: dict[int, float] = {}       # wall time of each input stream's last message
        self._first_input_wall: float | None = None
        self._last_processed: float | None = None
        self._last_motion_stamp: dict[int, float] = {}
        self._motion_seen = False
        self._last_enqueue_wall = time.monotonic()
        self._pending_jump = False
        self._paused = False

        # Output state.
        self._odom_history: deque = deque(maxlen=400)
        self._map_to_odom: np.ndarray | None = None
        self._last_tf_ns = -1
        self._path = PathHistory(s.path_max_length, s.path_publish_max_poses)
        self._corrected: Counter = Counter()       # inputs used after a repair (normalised quaternions)
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
        self._last_reset_reason = ""
        self._drops_reported = 0

        # Publishers.
        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, "~/pose", latched_qos())
        self._path_pub = self.create_publisher(Path, "~/path", latched_qos())
        self._particles_pub = self.create_publisher(PoseArray, "~/particles", QoSProfile(depth=5))
        self._landmarks_pub = self.create_publisher(PointCloud2, "~/landmarks", latched_qos())
        self._markers_pub = self.create_publisher(MarkerArray, "~/landmark_markers", latched_qos())
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", QoSProfile(depth=10))
        self._tf = _TransformSender(self)

        # Subscriptions.
        input_qos = QoSProfile(
            depth=s.input_depth, history=HistoryPolicy.KEEP_LAST, durability=DurabilityPolicy.VOLATILE,
            reliability=(ReliabilityPolicy.RELIABLE if s.input_reliability == "reliable"
                         else ReliabilityPolicy.BEST_EFFORT))
        self._odom_sub = self.create_subscription(Odometry, s.odom_topic, self._on_odom, input_qos,
                                                  event_callbacks=self._events(s.odom_topic))
        self._control_sub = None
        if s.motion_source == "control":
            self._control_sub = self.create_subscription(TwistStamped, s.control_topic, self._on_control,
                                                         input_qos, event_callbacks=self._events(s.control_topic))
        self._obs_sub = self.create_subscription(PointCloud2, s.observations_topic, self._on_observations,
                                                 input_qos, event_callbacks=self._events(s.observations_topic))

        # Services.
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self.create_service(SetBool, "~/pause", self._srv_pause)
        self.create_service(Trigger, "~/save_map", self._srv_save_map)
        self.create_service(Trigger, "~/load_map", self._srv_load_map)

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

        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        if s.load_map_on_start:
            self._log_result(*self._load_map())
        self.get_logger().info(
            f"online EM SLAM: motion_source={s.motion_source} (model {self._config.motion.model}), "
            f"{self._config.filter.num_particles} particles, EM {self._config.em.algorithm}; "
            f"map -> odom via {self._tf.kind}" + ("" if s.publish_tf else " (publish_tf is false)"))

    # ------------------------------------------------------------------ helpers
    def _events(self, topic: str) -> SubscriptionEventCallbacks:
        def incompatible(info) -> None:
            self.get_logger().error(
                f"publisher on {topic!r} has an incompatible QoS (policy {info.last_policy_kind}); "
                "for best-effort publishers set input_qos.reliability: best_effort",
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
    def _on_odom(self, msg: Odometry) -> None:
        received = time.monotonic()
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        yaw, quaternion_problem = conv.odometry_yaw(q)
        pose = np.array([p.x, p.y, yaw], dtype=float)
        with self._lock:
            if quaternion_problem == "degenerate_quaternion":
                self._drop(quaternion_problem)
                self.get_logger().warning("dropped odometry with a degenerate (zero or yaw-less) orientation "
                                          f"quaternion ({q.x}, {q.y}, {q.z}, {q.w})",
                                          throttle_duration_sec=self._settings.warn_throttle_period)
                return
            if not np.all(np.isfinite(pose)) or not np.isfinite([q.x, q.y, q.z, q.w]).all():
                self._drop("non_finite_odometry")
                self.get_logger().warning("dropped odometry with non-finite pose",
                                          throttle_duration_sec=self._settings.warn_throttle_period)
                return
            if quaternion_problem:                   # used after normalisation: counted, not dropped
                self._corrected[quaternion_problem] += 1
            self._enqueue(conv.stamp_to_sec(msg.header.stamp), ODOM, pose, received)

    def _on_control(self, msg: TwistStamped) -> None:
        received = time.monotonic()
        control = np.array([msg.twist.linear.x, msg.twist.angular.z], dtype=float)
        with self._lock:
            if not np.all(np.isfinite(control)):
                self._drop("non_finite_control")
                self.get_logger().warning("dropped control with non-finite speed or angle",
                                          throttle_duration_sec=self._settings.warn_throttle_period)
                return
            stamp = conv.stamp_to_sec(msg.header.stamp)
            if stamp == 0.0:
                stamp = self._now_sec()      # unstamped twist: use the arrival time
            self._enqueue(stamp, CONTROL, control, received)

    def _on_observations(self, msg: PointCloud2) -> None:
        received = time.monotonic()
        with self._lock:
            try:
                # Observations with invalid ids, zero ranges or wild bearings are left out and counted.
                observations = conv.observations_from_cloud(msg, drops=self._drops)
            except ValueError as error:      # CloudFormatError is a ValueError
                self._drop("malformed_cloud")
                self.get_logger().warning(f"dropped malformed observation cloud: {error}",
                                          throttle_duration_sec=self._settings.warn_throttle_period)
                return
            if len(observations) == 0:
                self._drop("empty_cloud")
                return
            self._enqueue(conv.stamp_to_sec(msg.header.stamp), OBSERVATIONS, observations, received)

    # ------------------------------------------------------------------ buffer and processing
    def _enqueue(self, stamp: float, kind: int, payload, received: float) -> None:
        self._inputs += 1
        self._window_inputs += 1
        if self._paused:
            self._drop("paused")
            return
        if not math.isfinite(stamp):
            self._drop("non_finite_stamp")
            return
        self._check_clock_jump()
        s = self._settings
        # A jump back is judged per input stream: streams lagging each other are reordered
        # (input_delay) or dropped as out_of_order, never mistaken for a restart.
        previous = self._newest_by_kind.get(kind)
        if s.reset_on_time_jump and previous is not None and stamp < previous - s.time_jump_threshold:
            self._reset(f"{_KIND_NAME[kind]} stamp jumped back {previous - stamp:.3f} s")
        self._newest_by_kind[kind] = max(stamp, self._newest_by_kind.get(kind, stamp))
        if self._last_processed is not None and stamp < self._last_processed:
            self._drop("out_of_order")
            self.get_logger().warning(
                f"dropped {_KIND_NAME[kind]} stamped {self._last_processed - stamp:.3f} s before the last "
                "processed input (raise input_delay to reorder late inputs)",
                throttle_duration_sec=s.warn_throttle_period)
            return
        self._newest = stamp if self._newest is None else max(self._newest, stamp)
        self._seq += 1
        heapq.heappush(self._buffer, (stamp, kind, self._seq, payload, received))
        now = time.monotonic()
        self._last_enqueue_wall = now
        self._stream_wall[kind] = now
        if self._first_input_wall is None:
            self._first_input_wall = now
        self._drain(self._watermark(now))

    def _expected_streams(self) -> tuple[int, ...]:
        return (ODOM, OBSERVATIONS, CONTROL) if self._control_sub is not None else (ODOM, OBSERVATIONS)

    def _watermark(self, now: float) -> float:
        """Stamp up to which every input is known to have arrived.

        Each stream is ordered, so an input is safe to process once every active
        stream has delivered something at least as recent: the buffer then loses
        nothing however fast a bag is replayed or however late one topic lags.
        A stream silent for ``input_delay`` wall seconds (or never seen that long
        after the first input) stops holding the others back.
        """
        delay = self._settings.input_delay
        if delay <= 0:
            return math.inf
        marks = []
        for kind in self._expected_streams():
            seen = self._stream_wall.get(kind)
            if seen is None:
                if now - self._first_input_wall < delay:
                    marks.append(-math.inf)
            elif now - seen < delay:
                marks.append(self._newest_by_kind[kind])
        return min(marks) if marks else math.inf

    def _drain(self, limit: float) -> None:
        processed = False
        while self._buffer and self._buffer[0][0] <= limit:
            stamp, kind, _, payload, received = heapq.heappop(self._buffer)
            try:
                processed |= self._process(stamp, kind, payload)
            except Exception as error:  # noqa: BLE001 - bad input must never stop the node
                self._drop("internal_error")
                self.get_logger().error(f"failed to process {_KIND_NAME[kind]} at {stamp:.3f}: {error!r}",
                                        throttle_duration_sec=self._settings.warn_throttle_period)
            self._latencies.append(time.monotonic() - received)
        if processed:
            self._after_update()

    def _process(self, stamp: float, kind: int, payload) -> bool:
        throttle = self._settings.warn_throttle_period
        if self._last_processed is not None and stamp < self._last_processed:
            self._drop("out_of_order")
            return False
        if kind in (ODOM, CONTROL):
            if self._last_motion_stamp.get(kind) == stamp:
                self._drop("zero_time_step")
                self.get_logger().warning(f"dropped {_KIND_NAME[kind]} repeating the previous stamp",
                                          throttle_duration_sec=throttle)
                return False
            self._last_motion_stamp[kind] = stamp
        if kind == ODOM:
            self._odom_history.append((stamp, payload))
            if self._settings.motion_source == "odom":
                if not self._slam.add_odometry(stamp, payload):
                    return False
                self._motion_seen = True
        elif kind == CONTROL:
            if not self._slam.add_control(stamp, payload):
                return False
            self._motion_seen = True
        else:
            if not self._motion_seen:
                self._drop("no_motion_input")
                self.get_logger().warning("dropped observations received before any "
                                          f"{'odometry' if self._settings.motion_source == 'odom' else 'control'}",
                                          throttle_duration_sec=throttle)
                return False
            report = self._slam.add_observations(stamp, payload)
            if report.dropped:
                self.get_logger().warning(
                    "observations dropped by the estimator: "
                    + ", ".join(f"{k}={v}" for k, v in sorted(report.dropped.items())),
                    throttle_duration_sec=throttle)
            if math.isfinite(report.ess):
                self._last_ess = float(report.ess)
            self._updates += 1
            self._window_updates += 1
            self._map_dirty = True
            self._publish_particles()
        self._last_processed = stamp if self._last_processed is None else max(self._last_processed, stamp)
        return True

    # ------------------------------------------------------------------ outputs
    def _after_update(self) -> None:
        stamp = self._slam.last_stamp
        if stamp is None:
            return
        estimate = self._slam.pose()
        header = self._header(stamp, self._settings.map_frame)
        msg = conv.pose_to_msg(header, estimate)
        if msg is None:
            self._drop("non_finite_estimate")
            self.get_logger().error("estimate is not finite; pose not published",
                                    throttle_duration_sec=self._settings.warn_throttle_period)
            return
        self._pose_pub.publish(msg)
        self._path.append(stamp, estimate.mean)      # compact; messages are built at publish time
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
                "queued_inputs": len(self._buffer),
                "paused": self._paused,
                "resets": self._resets,
                "last_stamp": self._slam.last_stamp if self._slam.last_stamp is not None else -1.0,
                "dropped_total": total,
            }
            values.update({f"dropped.{reason}": count for reason, count in sorted(drops.items())})
            values.update({f"corrected.{reason}": count for reason, count in sorted(self._corrected.items())})
            level, message = DiagnosticStatus.OK, f"{len(landmarks)} landmarks"
            if self._paused:
                level, message = DiagnosticStatus.WARN, "paused"
            elif total > self._drops_reported:
                level = DiagnosticStatus.WARN
                message += f", {total - self._drops_reported} inputs dropped in the last {span:.1f} s"
            elif self._updates == 0:
                message = "waiting for observations"
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
        if not self._pending_jump:
            return
        self._pending_jump = False
        s = self._settings
        now = self._now_sec()
        if s.reset_on_time_jump and self._newest is not None and self._newest > now + s.time_jump_threshold:
            self._reset(f"clock jumped back to {now:.3f} s")

    def _housekeeping(self) -> None:
        with self._lock:
            self._check_clock_jump()
            # Inputs held for reordering are processed once no newer input came for a while,
            # and a stream that went silent stops holding the others back.
            if self._buffer:
                now = time.monotonic()
                if now - self._last_enqueue_wall > self._settings.input_delay + 0.2:
                    self._drain(math.inf)
                else:
                    self._drain(self._watermark(now))

    def _reset(self, reason: str) -> None:
        with self._lock:
            s = self._settings
            if self._pending_config is not None:
                self._core_drops_carry.update(self._slam.drops)
                self._config = self._pending_config
                self._pending_config = None
                self._slam = OnlineEMSlam(self._config, initial_pose=s.initial_pose)
            else:
                self._slam.reset(initial_pose=s.initial_pose, stamp=None)
            self._buffer.clear()
            self._newest = self._last_processed = None
            self._newest_by_kind.clear()
            self._stream_wall.clear()
            self._first_input_wall = None
            self._last_motion_stamp.clear()
            self._motion_seen = False
            self._odom_history.clear()
            self._map_to_odom = None
            self._last_tf_ns = -1
            self._path.clear()
            self._map_dirty = True
            self._last_ess = float("nan")
            self._resets += 1
            self._last_reset_reason = reason
            self.get_logger().warning(f"estimate reset: {reason}")

    # ------------------------------------------------------------------ services
    def _srv_reset(self, request, response):
        self._reset("reset service")
        response.success, response.message = True, "estimate and map reset"
        return response

    def _srv_pause(self, request, response):
        with self._lock:
            self._paused = bool(request.data)
        response.success = True
        response.message = "paused: inputs are ignored" if self._paused else "resumed"
        self.get_logger().info(response.message)
        return response

    def _map_directory(self) -> str:
        s = self._settings
        directory = s.map_directory.strip() or os.path.dirname(os.path.expanduser(s.map_file.strip()))
        return os.path.abspath(os.path.expanduser(directory or "."))

    def _map_path(self) -> str:
        """map_file resolved inside map_directory (MapFileError if it escapes: '..', symlinks)."""
        return confined_path(self._settings.map_file, self._map_directory())

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
                self._slam.save_map(path)    # validated, fsynced temporary file + rename (core/mapfile.py)
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
