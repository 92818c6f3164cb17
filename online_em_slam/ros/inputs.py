"""The node's inputs: subscriptions, decoding and the input pipeline.

  ``odom``                   nav_msgs/Odometry: motion input when motion_source = odom,
                             and always the odom -> base pose for map -> odom.
  ``control``                geometry_msgs/TwistStamped (motion_source = control):
                             linear.x speed, angular.z steering angle or yaw rate.
  ``landmark_observations``  sensor_msgs/PointCloud2 with fields range, bearing
                             [, id (-1 unknown), range_std, bearing_std].

Each callback decodes its message and hands it to the
:class:`~online_em_slam.pipeline.InputPipeline` (the one the offline runner
uses), which applies what it releases to the estimator and calls the outputs
back.  Every message with a readable stamp tells the pipeline its stream is
alive, used or not; an input that cannot be used is dropped and counted by
reason, with a throttled warning.  When the node cannot keep up with
best-effort inputs it sheds observation updates (``dropped.overload``), never
motion: while the last motion input (or the cloud itself) waited longer than
``input_max_wait`` in its subscription's queue (from the message's reception
time in its MessageInfo), a cloud is not even decoded; and while the share of
time spent on inputs exceeds the load limit the pipeline skips updates.
Reliable inputs are never shed (the publisher waits).
"""
from __future__ import annotations

import time
from collections import Counter

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.event_handler import SubscriptionEventCallbacks
from sensor_msgs.msg import PointCloud2

from ..pipeline import CONTROL, KIND_NAME, OBSERVATIONS, ODOMETRY, InputPipeline
from . import conversions as conv
from .input_watch import InputWatch, Stream, publishers_text
from .qos import input_qos
from .queue_drain import draining
from .tf import SensorFrames

# Odometry positions beyond this (m) are absurd (the map's coordinate range, as initial_pose.*).
ODOMETRY_POSITION_LIMIT = 1e7


class Inputs:
    """Subscriptions and the input pipeline (``node``: OnlineEmSlamNode)."""

    def __init__(self, node, outputs, diagnostics) -> None:
        self.node = node
        self.outputs = outputs
        self.diagnostics = diagnostics
        s = node.settings
        self.corrected: Counter = Counter()       # inputs used after a repair (normalised quaternions)
        self.frames = SensorFrames(node)          # frame ids checked; the sensor pose from TF (tf2_ros)
        self.watch = InputWatch()                 # silent input streams turn diagnostics WARN
        self.pending_jump = False
        self.pipeline = InputPipeline(node.slam, s.motion_source, s.input_delay, s.time_jump_threshold,
                                      restart_on_jump_back=s.reset_on_time_jump,
                                      shedding=self.sheds(s), max_wait=s.input_max_wait,
                                      on_applied=outputs.applied,
                                      on_settled=outputs.settled, on_jump=self._on_jump)
        self.motion_kind = self.pipeline.motion_kind
        self.odom_sub = self.control_sub = self.obs_sub = None
        self._unheard_warned: set[str] = set()

    def subscribe(self) -> None:
        """The input subscriptions (the lifecycle's activate); silent until heard."""
        node, s = self.node, self.node.settings
        qos = input_qos(s.input_reliability, s.input_depth)
        self.odom_sub = node.create_subscription(Odometry, s.odom_topic, self._reader(ODOMETRY), qos,
                                                 event_callbacks=self._events(s.odom_topic))
        if s.motion_source == "control":
            self.control_sub = node.create_subscription(TwistStamped, s.control_topic, self._reader(CONTROL),
                                                        qos, event_callbacks=self._events(s.control_topic))
        self.obs_sub = node.create_subscription(PointCloud2, s.observations_topic, self._reader(OBSERVATIONS),
                                                qos, event_callbacks=self._events(s.observations_topic))
        now = time.monotonic()
        self.watch.clear(now)
        for sub, key, parameter, required in (
                (self.odom_sub, s.odom_topic, "odom_topic", s.motion_source == "odom"),
                (self.control_sub, s.control_topic, "control_topic", True),
                (self.obs_sub, s.observations_topic, "observations_topic", True)):
            if sub is not None:
                self.watch.expect(Stream(key, sub.topic_name, parameter, required), now)
        self._unheard_warned = set()

    def _reader(self, kind: int):
        """The subscription callback of ``kind``: its message, then those queued behind it while the
        stream may be read ahead (queue_drain.py); a motion queue found empty has no lag."""
        handle, subscription = {ODOMETRY: (self.on_odom, lambda: self.odom_sub),
                                CONTROL: (self.on_control, lambda: self.control_sub),
                                OBSERVATIONS: (self.on_observations, lambda: self.obs_sub)}[kind]
        emptied = (lambda: None) if kind == OBSERVATIONS else (lambda: self.pipeline.waited(0.0))
        return draining(handle, subscription, self.pipeline.read_ahead_span, emptied)

    def unsubscribe(self) -> None:
        """No more inputs (the lifecycle's deactivate); the estimate and the queue's counters stay."""
        for sub in (self.odom_sub, self.control_sub, self.obs_sub):
            if sub is not None:
                self.node.destroy_subscription(sub)
        self.odom_sub = self.control_sub = self.obs_sub = None
        self.watch = InputWatch()

    @staticmethod
    def sheds(settings) -> bool:
        """Shedding keeps best-effort queues from overflowing; with reliable (KEEP_ALL) inputs
        the publisher waits instead, so a lossless replay is never shed."""
        return settings.input_reliability != "reliable"

    def apply_settings(self, settings) -> None:
        """Parameters changed at run time: the merge window and shedding follow."""
        self.pipeline.set_input_delay(settings.input_delay)
        self.pipeline.shedding = self.sheds(settings)
        self.pipeline.max_wait = settings.input_max_wait

    def _events(self, topic: str) -> SubscriptionEventCallbacks:
        node = self.node

        def incompatible(info) -> None:
            node.throttle.error(f"incompatible_qos:{topic}",
                                f"publisher on {topic!r} has an incompatible QoS (policy {info.last_policy_kind}); "
                                "for best-effort publishers set input_qos.reliability: best_effort (the default)")

        def lost(info) -> None:
            with node.lock:
                node.drops["message_lost"] += int(info.total_count_change)
        return SubscriptionEventCallbacks(incompatible_qos=incompatible, message_lost=lost)

    # ------------------------------------------------------------------ callbacks
    # ``info``: the MessageInfo of a message read from the queue behind another (queue_drain.py);
    # how long it waited there is the node's lag behind its inputs.
    def on_odom(self, msg: Odometry, info=None) -> None:
        node = self.node
        started = time.monotonic()
        self._waited(ODOMETRY, info)
        self.watch.heard(node.settings.odom_topic, started)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        yaw, quaternion_problem = conv.odometry_yaw(q)
        pose = np.array([p.x, p.y, yaw], dtype=float)
        with node.lock:
            s = node.settings
            self.frames.check_odometry(msg.child_frame_id, s, msg.header.frame_id)
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
                self.corrected[quaternion_problem] += 1
            # A lone bad stamp (0, far future) must not stamp ~/pose or map -> odom: one
            # pose at 2^31 s would hold back every later one.
            on_time_line = self.pipeline.on_time_line(ODOMETRY, stamp)
            if on_time_line:
                self.outputs.remember_odometry(stamp, pose)
            if self.motion_kind == ODOMETRY:
                self._input(ODOMETRY, stamp, pose, started)
            else:
                self.diagnostics.count_input()      # odometry only places map -> odom and ~/pose
                if on_time_line:
                    self.pipeline.watch(ODOMETRY, stamp)
                else:
                    node.drops["stamp_outlier"] += 1
            if on_time_line:
                self.outputs.publish_odometry_pose(stamp, pose)
            self.pipeline.busy(time.monotonic(), time.monotonic() - started)

    def on_control(self, msg: TwistStamped, info=None) -> None:
        node = self.node
        started = time.monotonic()
        self._waited(CONTROL, info)
        self.watch.heard(node.settings.control_topic, started)
        control = np.array([msg.twist.linear.x, msg.twist.angular.z], dtype=float)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        with node.lock:
            if stamp == 0.0:
                stamp = node.now_sec()      # unstamped twist: use the arrival time
            if not np.all(np.isfinite(control)):
                self._refuse(CONTROL, stamp, "non_finite_control", "control with non-finite speed or angle",
                             started)
                return
            self._input(CONTROL, stamp, control, started)
            self.pipeline.busy(time.monotonic(), time.monotonic() - started)

    def on_observations(self, msg: PointCloud2, info=None) -> None:
        node = self.node
        started = time.monotonic()
        self.watch.heard(node.settings.observations_topic, started)
        stamp = conv.stamp_to_sec(msg.header.stamp)
        with node.lock:
            if self.pipeline.overdue(self._waited(OBSERVATIONS, info)) and not node.paused:
                self.diagnostics.count_input()       # received, not read: counted as overload
                self.pipeline.shed(OBSERVATIONS, stamp, started)
                self.pipeline.busy(time.monotonic(), time.monotonic() - started)
                return
            try:
                # Observations with invalid ids, zero ranges or wild bearings are left out and counted.
                observations = conv.observations_from_cloud(msg, drops=node.drops)
            except ValueError as error:      # CloudFormatError is a ValueError
                self._refuse(OBSERVATIONS, stamp, "malformed_cloud", f"malformed observation cloud: {error}",
                             started)
                return
            # Into the estimator's sensor frame: through TF when it resolves the cloud's frame.
            observations = self.frames.observations(msg.header.frame_id, stamp, observations, node.settings,
                                                    node.slam.config.sensor)
            # An empty cloud goes through the merge too: it says "nothing seen up to here".
            self._input(OBSERVATIONS, stamp, observations, started)
            self.pipeline.busy(time.monotonic(), time.monotonic() - started)

    def _waited(self, kind: int, info) -> float:
        """How long the message waited in its queue (s; 0 when not known): the lag, into the pipeline
        and /diagnostics."""
        if info is None:
            return 0.0
        seconds = conv.queue_wait(info)
        self.diagnostics.waited(seconds)
        if kind != OBSERVATIONS:
            self.pipeline.waited(seconds)
        return seconds

    def _refuse(self, kind: int, stamp: float, reason: str, what: str, started: float) -> None:
        """An input whose payload is unusable: counted, and its stamp still advances its stream."""
        node = self.node
        node.drops[reason] += 1
        node.throttle.warning(f"refused:{reason}", f"dropped {what}")
        if not node.paused and kind in (self.motion_kind, OBSERVATIONS):
            self.pipeline.heard(kind, stamp, started)

    def _input(self, kind: int, stamp: float, payload, started: float) -> None:
        # An empty cloud is counted as decided.empty_cloud; one the reader emptied was a cloud of
        # points, each counted under its reason, and is an input received.
        if kind != OBSERVATIONS or len(payload) or getattr(payload, "refused_points", 0):
            self.diagnostics.count_input()
        if self.node.paused:
            self.node.drops["paused"] += 1
            return
        self.check_clock_jump()
        self.pipeline.push(kind, stamp, payload, started)

    def _on_jump(self, jump, restarted: bool) -> None:
        """A confirmed jump of the input stamps (before the inputs it released are applied)."""
        if restarted:
            self.node.reset(f"{KIND_NAME[jump.released[0].kind]} stamps jumped back {jump.size:.3f} s "
                            f"(confirmed by {len(jump.released)} inputs)", keep_inputs=True, keep_map=True)
        else:
            self.node.get_logger().warning(f"input stamps jumped {'back' if jump.backward else 'ahead'} "
                                           f"{jump.size:.3f} s (confirmed by {len(jump.released)} inputs)")

    # ------------------------------------------------------------------ time
    def on_clock_jump(self, jump) -> None:
        # Runs inside the clock update: only note it; the reset happens in check_clock_jump.
        self.pending_jump = True

    def check_clock_jump(self) -> None:
        """A /clock jump back confirms a time jump by itself (bag played in a loop)."""
        if not self.pending_jump:
            return
        self.pending_jump = False
        node, s = self.node, self.node.settings
        now = node.now_sec()
        newest = self.pipeline.newest
        if s.reset_on_time_jump and newest is not None and newest > now + s.time_jump_threshold:
            node.reset(f"clock jumped back to {now:.3f} s", keep_map=True)

    def housekeeping(self) -> None:
        """Periodic: a /clock jump, a stream that went silent stops holding the others back, and a
        subscribed topic that never delivered while others do is warned about (once)."""
        with self.node.lock:
            self.check_clock_jump()
            self.pipeline.release(time.monotonic())
            self.warn_unheard(time.monotonic())

    def publishers(self, stream: Stream) -> int:
        return self.node.count_publishers(stream.topic)

    def warn_unheard(self, now: float) -> None:
        """One warning per subscribed topic that has delivered nothing while another input has,
        with its publisher count and the topics of its type that do have publishers."""
        node = self.node
        if not self.watch.any_heard():
            return
        for stream in self.watch.unheard(now, node.settings.input_delay):
            if stream.key in self._unheard_warned:
                continue
            self._unheard_warned.add(stream.key)
            others = self._same_type_topics(stream)
            node.get_logger().warning(
                f"nothing received on {stream.topic} ({stream.parameter}; {publishers_text(self.publishers(stream))}) "
                "while other inputs arrive" + (f"; topics of its type with publishers: {', '.join(others)}"
                                               if others else "")
                + ("" if stream.required else " (optional: odometry only places map -> odom)"))

    def _same_type_topics(self, stream: Stream) -> list[str]:
        kinds = {"odom_topic": "nav_msgs/msg/Odometry", "control_topic": "geometry_msgs/msg/TwistStamped",
                 "observations_topic": "sensor_msgs/msg/PointCloud2"}
        try:
            topics = self.node.get_topic_names_and_types()
        except Exception:       # noqa: BLE001 (a graph query failing must not stop the housekeeping)
            return []
        return [name for name, types in topics if kinds[stream.parameter] in types and name != stream.topic
                and self.node.count_publishers(name) > 0][:3]
