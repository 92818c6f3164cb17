"""End-to-end tests of the ROS 2 node with real rclpy, in one process.

Each test gets a fresh Context and executor; the node under test and a
tester node exchange real messages (discovery limited to the process by
ROS_AUTOMATIC_DISCOVERY_RANGE=OFF, set in conftest.py before rclpy loads).
"""
import math
import os
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"

import numpy as np  # noqa: E402
import pytest  # noqa: E402

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import (PoseArray, PoseWithCovarianceStamped, TransformStamped,  # noqa: E402
                               TwistStamped)
from nav_msgs.msg import Odometry, Path  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from online_em_slam.messages.cloud import decode_message  # noqa: E402
from online_em_slam.ros import conversions as conv  # noqa: E402
from online_em_slam.ros.node import OnlineEmSlamNode, latched_qos  # noqa: E402
from online_em_slam.parameters.specs import ParameterError  # noqa: E402
from online_em_slam.experiments.simulation import ScenarioConfig, simulate  # noqa: E402

NAME = "online_em_slam"
T0 = 1000.0            # stamps start here (a zero stamp means "unstamped" for controls)
TIMEOUT_SCALE = float(os.environ.get("LIVE_TIMEOUT_SCALE", "3"))   # Harness.spin_until
# Parameters of every live test's node. Lossless inputs (the testers publish reliably): a loaded
# test machine must not make a node shed observation updates where a test counts them or compares
# maps; the shedding tests ask for best_effort.
LIVE_DEFAULTS = {"map_publish_period": 0.1, "diagnostics_period": 0.2, "transform_publish_period": 0.05,
                 "warn_throttle_period": 0.0, "input_delay": 0.0, "input_qos.reliability": "reliable"}


def finite_pose(msg: PoseWithCovarianceStamped) -> bool:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return all(math.isfinite(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w, *msg.pose.covariance))


class Harness:
    """A node under test, a tester node with publishers/subscribers, and spin helpers."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.tester = rclpy.create_node("tester", context=self.context)
        self.executor.add_node(self.tester)
        self.node = None
        self.received = {}
        self._subs = []

    # -- setup
    def start(self, **params) -> OnlineEmSlamNode:
        base = {**LIVE_DEFAULTS, **params}
        overrides = [Parameter(k, value=v) for k, v in base.items()]
        self.node = OnlineEmSlamNode(context=self.context, parameter_overrides=overrides)
        self.executor.add_node(self.node)
        qos_in = rclpy.qos.QoSProfile(depth=1000, reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        self.odom_pub = self.tester.create_publisher(Odometry, "/odom", qos_in)
        self.control_pub = self.tester.create_publisher(TwistStamped, "/control", qos_in)
        self.cloud_pub = self.tester.create_publisher(PointCloud2, "/landmark_observations", qos_in)
        self.clock_pub = self.tester.create_publisher(ClockMsg, "/clock", 10)
        for topic, kind, qos in (("pose", PoseWithCovarianceStamped, latched_qos()),
                                 ("path", Path, latched_qos()),
                                 ("particles", PoseArray, 10),
                                 ("landmarks", PointCloud2, latched_qos()),
                                 ("landmark_markers", MarkerArray, latched_qos())):
            self.subscribe(f"/{NAME}/{topic}", kind, qos, topic)
        self.subscribe_map_to_odom()
        self.subscribe("/diagnostics", DiagnosticArray, 10, "diagnostics")
        return self.node

    def subscribe_map_to_odom(self) -> None:
        """received["map_to_odom"]: map -> odom where the node sends it, /tf when tf2_ros or
        tf2_msgs is importable (make install builds tf2_msgs), else ~/map_to_odom."""
        if not self.node.outputs.transform.kind.startswith("tf2"):
            return self.subscribe(f"/{NAME}/map_to_odom", TransformStamped, 100, "map_to_odom")
        from tf2_msgs.msg import TFMessage
        received = self.received["map_to_odom"] = []
        odom = self.node.get_parameter("odom_frame").value
        self._subs.append(self.tester.create_subscription(
            TFMessage, "/tf", lambda msg: received.extend(t for t in msg.transforms if t.child_frame_id == odom), 100))

    def subscribe(self, topic, kind, qos, key):
        self.received[key] = []
        self._subs.append(self.tester.create_subscription(kind, topic, self.received[key].append, qos))

    def close(self) -> None:
        self.executor.shutdown()
        if self.node is not None:
            self.node.destroy_node()
        self.tester.destroy_node()
        rclpy.shutdown(context=self.context)

    # -- spinning
    def spin_until(self, condition, timeout=10.0) -> bool:
        """Spin until ``condition()`` holds, at most ``timeout`` s times TIMEOUT_SCALE: no test waits
        for a condition that should not come, so a longer bound costs only a failing test time,
        and a loaded CI machine, where the node runs several times slower, gets room."""
        deadline = time.monotonic() + timeout * TIMEOUT_SCALE
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return bool(condition())

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def call(self, srv_type, name, request, timeout=10.0):
        client = self.tester.create_client(srv_type, f"/{NAME}/{name}")
        assert self.spin_until(client.service_is_ready, timeout), f"service {name} not available"
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"service {name} did not answer"
        self.tester.destroy_client(client)
        return future.result()

    # -- publishing
    def odom(self, stamp, x, y, yaw):
        msg = Odometry(header=Header(stamp=conv.sec_to_stamp(stamp), frame_id="odom"), child_frame_id="base_link")
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
        msg.pose.pose.orientation = conv.yaw_to_quaternion(yaw) if math.isfinite(yaw) else \
            type(msg.pose.pose.orientation)(z=float("nan"), w=1.0)
        self.odom_pub.publish(msg)

    def control(self, stamp, v, steer):
        msg = TwistStamped(header=Header(stamp=conv.sec_to_stamp(stamp), frame_id="base_link"))
        msg.twist.linear.x, msg.twist.angular.z = float(v), float(steer)
        self.control_pub.publish(msg)

    def cloud(self, stamp, ranges, bearings, ids=None):
        header = Header(stamp=conv.sec_to_stamp(stamp), frame_id="sensor")
        self.cloud_pub.publish(conv.observations_to_cloud(header, ranges, bearings, ids))

    def clock(self, seconds):
        self.clock_pub.publish(ClockMsg(clock=conv.sec_to_stamp(seconds)))

    # -- reading
    def diagnostics(self) -> dict:
        if not self.received["diagnostics"]:
            return {}
        status = self.received["diagnostics"][-1].status[0]
        return {kv.key: kv.value for kv in status.values}

    def drops(self) -> dict:
        return {k[len("dropped."):]: int(v) for k, v in self.diagnostics().items() if k.startswith("dropped.")}

    def decided(self) -> dict:
        return {k[len("decided."):]: int(v) for k, v in self.diagnostics().items() if k.startswith("decided.")}


def landmark_table(msg: PointCloud2) -> dict:
    columns = decode_message(msg, required=("x", "y", "id"))
    return {int(i): (float(x), float(y)) for i, x, y in zip(columns["id"], columns["x"], columns["y"])}


# ----------------------------------------------------------------- scenario
def scenario(n_steps=300):
    """Steps of (control stamp, control, scan stamp, ranges, bearings, ids), truth, initial pose and
    the parameters of the simulation's model: its true noise, given (the node's default learns it)."""
    sc = simulate(ScenarioConfig(n_steps=n_steps, seed=1))
    steps = [(T0 + s.control_stamp, s.control, T0 + s.stamp, s.ranges, s.bearings, s.ids) for s in sc.steps]
    params = {"motion.wheelbase": sc.config.wheelbase, "motion.sigma_speed": sc.config.sigma_speed,
              "motion.sigma_steering": sc.config.sigma_steering,
              "motion.noise_reference_period": sc.config.dt, "sensor.max_range": sc.config.max_range,
              "noise.sigma_range": sc.config.sigma_range, "noise.sigma_bearing": sc.config.sigma_bearing,
              "noise.rho": sc.config.rho, "noise.model": "gaussian", "noise_learning.enabled": False}
    return steps, sc.true_poses, sc.landmarks, sc.initial_pose, params


# ----------------------------------------------------------------- tests
def test_simulated_run_converges_late_subscriber_and_services(ros, tmp_path):
    steps, truth, landmarks, initial, model = scenario(300)
    (tmp_path / "maps").mkdir()
    map_file = str(tmp_path / "maps" / "map.npz")
    node = ros.start(motion_source="control", control_angular="steering", input_delay=1.2,
                     **{"filter.num_particles": 50, "initial_pose.x": float(initial[0]),
                        "initial_pose.y": float(initial[1]), "initial_pose.yaw": float(initial[2]),
                        "map_file": map_file}, **model)
    n_scans = sum(1 for s in steps if len(s[3]))
    # Chunks of 1 s of data; the two topics may be delivered with some skew within a
    # chunk, which the node's reordering buffer (input_delay) absorbs.
    published = 0
    for start in range(0, len(steps), 5):
        for control_stamp, control, stamp, ranges, bearings, ids in steps[start:start + 5]:
            ros.control(control_stamp, *control)
            published += 1
            if len(ranges):
                ros.cloud(stamp, ranges, bearings, ids)
                published += 1
        assert ros.spin_until(lambda: node.inputs_received == published, 5.0)
    last = steps[-1][2]
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(last), 20.0)
    assert ros.spin_until(lambda: any(abs(conv.stamp_to_sec(m.header.stamp) - last) < 1e-6
                                      for m in ros.received["pose"]), 5.0)
    assert node.all_drops().get("out_of_order", 0) == 0

    # Pose converges: final error against the truth.
    final = [m for m in ros.received["pose"] if abs(conv.stamp_to_sec(m.header.stamp) - last) < 1e-6][-1]
    assert final.header.frame_id == "map" and finite_pose(final)
    error = math.hypot(final.pose.pose.position.x - truth[-1][0], final.pose.pose.position.y - truth[-1][1])
    assert error < 4.0, f"final position error {error:.2f} m"
    dead = np.array(initial, dtype=float)                # dead reckoning with the same noisy controls
    for _, (v, steer), *_ in steps:
        dead = dead + [v * 0.2 * math.cos(dead[2] + steer), v * 0.2 * math.sin(dead[2] + steer),
                       v * 0.2 * math.sin(steer) / model["motion.wheelbase"]]
    dead_error = math.hypot(dead[0] - truth[-1][0], dead[1] - truth[-1][1])
    assert error < 0.6 * dead_error, (error, dead_error)
    assert all(finite_pose(m) for m in ros.received["pose"])
    stamps = [conv.stamp_to_sec(m.header.stamp) for m in ros.received["pose"]]
    assert stamps == sorted(stamps) and min(stamps) >= T0      # input stamps, never wall time

    # Map converges: landmark RMSE (ids index the true landmarks).
    assert ros.spin_until(lambda: ros.received["landmarks"] and abs(
        conv.stamp_to_sec(ros.received["landmarks"][-1].header.stamp) - last) < 1e-6, 5.0)
    table = landmark_table(ros.received["landmarks"][-1])
    assert len(table) >= 0.8 * len({int(i) for s in steps for i in s[5]})
    err = [math.hypot(x - landmarks[i][0], y - landmarks[i][1]) for i, (x, y) in table.items()]
    rmse = math.sqrt(np.mean(np.square(err)))
    assert rmse < 2.5, f"landmark RMSE {rmse:.2f} m"
    print(f"simulated run: final position error {error:.2f} m (dead reckoning {dead_error:.2f} m), "
          f"landmark RMSE {rmse:.2f} m "
          f"({len(table)} landmarks)")
    assert ros.received["particles"] and ros.received["path"]
    assert 0 < len(ros.received["path"][-1].poses) <= 10000

    # Diagnostics report rates, latency, ESS and the map size.
    assert ros.spin_until(lambda: ros.diagnostics().get("observation_updates") == str(n_scans), 3.0), \
        (node.all_drops(), ros.diagnostics())
    diag = ros.diagnostics()
    assert diag["landmarks"] == str(len(table))
    assert 0 < float(diag["ess"]) <= 50 and float(diag["latency_max_ms"]) >= 0

    # A late subscriber still receives the latched map, markers and pose.
    late = {}
    for topic, kind in (("landmarks", PointCloud2), ("landmark_markers", MarkerArray),
                        ("pose", PoseWithCovarianceStamped)):
        late[topic] = []
        ros.tester.create_subscription(kind, f"/{NAME}/{topic}", late[topic].append, latched_qos())
    assert ros.spin_until(lambda: all(late.values()), 5.0)
    assert landmark_table(late["landmarks"][0]) == table
    markers = late["landmark_markers"][0].markers
    assert sum(m.type == m.TEXT_VIEW_FACING for m in markers) == len(table)

    # save -> reset -> load restores the same map.
    saved = ros.call(Trigger, "save_map_file", Trigger.Request())
    assert saved.success, saved.message
    assert os.path.exists(map_file) and not [f for f in os.listdir(os.path.dirname(map_file)) if "tmp" in f]
    reset = ros.call(Trigger, "reset", Trigger.Request())
    assert reset.success
    assert len(node.slam.landmarks()) == 0
    assert ros.spin_until(lambda: len(landmark_table(ros.received["landmarks"][-1])) == 0, 3.0)
    loaded = ros.call(Trigger, "load_map_file", Trigger.Request())
    assert loaded.success, loaded.message
    assert ros.spin_until(lambda: landmark_table(ros.received["landmarks"][-1]) == table, 3.0)

    # The loaded map continues estimation: the last scan seen again from the restored pose
    # updates the existing landmarks and creates none.
    n_obs_before = int(node.slam.landmarks().n_obs.sum())
    _, _, _, ranges, bearings, ids = [s for s in steps if len(s[3])][-1]
    for j in range(5):
        ros.control(T0 + 500.0 + 0.2 * j, 0.0, 0.0)
        ros.cloud(T0 + 500.2 + 0.2 * j, ranges, bearings, ids)
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 501.0), 5.0)
    after = node.slam.landmarks()
    assert len(after) == len(table) and int(after.n_obs.sum()) == n_obs_before + 5 * len(ids)
    moved = [math.hypot(x - table[int(i)][0], y - table[int(i)][1]) for i, (x, y) in zip(after.ids, after.positions)]
    assert max(moved) < 1.0

    # pause: inputs are ignored (and counted), resume processes again.
    assert ros.call(SetBool, "pause", SetBool.Request(data=True)).success
    before = node.slam.last_stamp
    ros.control(T0 + 600.0, 1.0, 0.0)
    ros.cloud(T0 + 600.0, ranges, bearings, ids)
    assert ros.spin_until(lambda: node.all_drops().get("paused", 0) == 2, 3.0)
    assert node.slam.last_stamp == before
    assert ros.call(SetBool, "pause", SetBool.Request(data=False)).success
    ros.control(T0 + 601.0, 1.0, 0.0)
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 601.0), 3.0)


def test_map_to_odom_transform(ros):
    node = ros.start(motion_source="odom", **{"initial_pose.x": 1.0, "initial_pose.y": 2.0,
                                              "initial_pose.yaw": 0.5})
    # The odometry frame starts at (3, -1, -0.2): map->odom maps it onto the initial pose.
    odom0 = np.array([3.0, -1.0, -0.2])
    for k in range(10):
        ros.odom(T0 + 0.1 * k, odom0[0] + 0.1 * k * math.cos(odom0[2]), odom0[1] + 0.1 * k * math.sin(odom0[2]),
                 odom0[2])
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 0.9), 5.0)
    assert ros.spin_until(lambda: len(ros.received["map_to_odom"]) >= 5, 5.0)
    tf = ros.received["map_to_odom"][-1]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "odom")
    expected = conv.pose2d_compose(np.array([1.0, 2.0, 0.5]), conv.pose2d_inverse(odom0))
    got = (tf.transform.translation.x, tf.transform.translation.y, conv.quaternion_to_yaw(tf.transform.rotation))
    assert np.allclose(got, expected, atol=0.05), (got, expected)
    stamps = [conv.stamp_to_sec(t.header.stamp) for t in ros.received["map_to_odom"]]
    assert all(b > a for a, b in zip(stamps, stamps[1:])), "map->odom stamps must strictly increase"
    assert node.slam.pose().mean[0] == pytest.approx(1.0 + 0.9 * math.cos(0.5), abs=0.05)


def test_backward_time_jump_restarts_the_pose_and_keeps_the_map(ros):
    node = ros.start(motion_source="odom", use_sim_time=True)
    ros.clock(T0)
    assert ros.spin_until(lambda: node.get_clock().now().nanoseconds == int(T0 * 1e9), 5.0)
    for k in range(5):
        ros.odom(T0 + 0.2 * k, 0.2 * k, 0.0, 0.0)
        ros.cloud(T0 + 0.2 * k, [5.0], [0.1], [7])
    ros.clock(T0 + 1.0)
    assert ros.spin_until(lambda: len(node.slam.landmarks()) == 1 and node.slam.last_stamp == T0 + 0.8, 5.0)

    # The clock jumps back (bag played in a loop): the pose and the time line restart, the
    # map stays (issue 12: an automatic reset keeps the map; only ~/reset wipes it).
    before = node.slam.landmarks().positions.copy()
    ros.clock(T0 - 100.0)
    assert ros.spin_until(lambda: node.slam.last_stamp is None, 5.0)
    np.testing.assert_array_equal(node.slam.landmarks().positions, before)
    ros.odom(T0 - 100.0, 0.0, 0.0, 0.0)
    assert ros.spin_until(lambda: node.slam.last_stamp == T0 - 100.0, 3.0)
    ros.cloud(T0 - 100.0, [5.0], [0.1], [7])                # the same landmark seen again: no new one
    assert ros.spin_until(lambda: node.slam.landmarks().n_obs[0] == 6, 3.0)
    assert len(node.slam.landmarks()) == 1

    # Input stamps jumping back (without a clock jump) reset too once three inputs confirm
    # the jump; small steps back are dropped.
    ros.odom(T0 - 99.0, 1.0, 0.0, 0.0)
    ros.odom(T0 - 99.5, 0.5, 0.0, 0.0)                  # 0.5 s back: out of order
    assert ros.spin_until(lambda: node.all_drops().get("out_of_order", 0) == 1, 3.0)
    for k in range(3):
        ros.odom(T0 - 200.0 + 0.1 * k, 0.1 * k, 0.0, 0.0)   # 99 s back, confirmed: reset
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 - 199.8), 3.0)
    assert ros.spin_until(lambda: ros.diagnostics().get("resets") == "2", 3.0)
    assert "stamp_outlier" not in node.all_drops()
    assert len(node.slam.landmarks()) == 1 and node.slam.landmarks().n_obs[0] == 6


def test_bad_inputs_are_counted_and_outputs_stay_finite(ros):
    node = ros.start(motion_source="odom")
    ros.cloud(T0, [5.0], [0.0], [1])                          # before any odometry
    assert ros.spin_until(lambda: node.all_drops().get("no_motion_input") == 1, 3.0)
    ros.odom(T0, 0.0, 0.0, 0.0)
    ros.odom(T0 + 0.1, 0.1, 0.0, 0.0)
    ros.cloud(T0 + 0.1, [5.0, 6.0], [0.0, 0.5], [1, 2])
    assert ros.spin_until(lambda: len(node.slam.landmarks()) == 2, 3.0)

    # Malformed clouds: a missing field, then a payload shorter than its fields claim.
    good = conv.observations_to_cloud(Header(stamp=conv.sec_to_stamp(T0 + 0.2)), [5.0], [0.0], [1])
    missing = PointCloud2(header=good.header, height=1, width=1, point_step=good.point_step,
                          row_step=good.row_step, fields=[f for f in good.fields if f.name != "bearing"],
                          data=good.data)
    short = PointCloud2(header=good.header, height=1, width=3, point_step=good.point_step,
                        row_step=3 * good.point_step, fields=list(good.fields), data=good.data)
    bad_type = PointCloud2(header=good.header, height=1, width=1, point_step=good.point_step,
                           row_step=good.point_step, data=good.data,
                           fields=[PointField(name="range", offset=0, datatype=42, count=1)])
    for msg in (missing, short, bad_type):
        ros.cloud_pub.publish(msg)
    ros.cloud(T0 + 0.2, [], [], [])                                          # empty
    assert ros.spin_until(lambda: node.all_drops().get("malformed_cloud") == 3
                          and node.all_drops().get("empty_cloud") == 1, 3.0)
    ros.odom(T0 + 0.3, 0.3, 0.0, 0.0)
    assert ros.spin_until(lambda: node.slam.last_stamp == T0 + 0.3, 3.0)
    ros.cloud(T0 + 0.3, [float("nan"), float("inf"), -2.0, 5.0], [0.0, 0.0, 0.0, 0.0], [1, 1, 1, 1])
    assert ros.spin_until(lambda: node.all_drops().get("invalid_observation") == 3, 3.0)
    ros.odom(T0 + 0.4, float("nan"), 0.0, 0.0)                               # non-finite position
    ros.odom(T0 + 0.4, 0.4, 0.0, float("nan"))                               # non-finite orientation
    assert ros.spin_until(lambda: node.all_drops().get("non_finite_odometry") == 2, 3.0)
    ros.odom(T0 + 0.4, 0.4, 0.0, 0.0)
    ros.odom(T0 + 0.4, 0.4, 0.0, 0.0)                                        # zero time step
    assert ros.spin_until(lambda: node.all_drops().get("zero_time_step") == 1, 3.0)
    ros.odom(T0 + 0.1, 0.1, 0.0, 0.0)                                        # older than the last one
    assert ros.spin_until(lambda: node.all_drops().get("out_of_order") == 1, 3.0)
    for k in range(3):                      # huge time step, taken once three inputs confirm it
        ros.odom(T0 + 30.4 + 0.1 * k, 0.5, 0.0, 0.0)
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 30.6), 3.0)
    ros.cloud(T0 + 30.6, [5.0, 6.0], [0.0, 0.5], [1, 2])
    expected = {"malformed_cloud": 3, "invalid_observation": 3, "non_finite_odometry": 2,
                "zero_time_step": 1, "out_of_order": 1, "no_motion_input": 1}
    # /diagnostics reports every counter; an empty cloud is a decision, not a drop.
    assert ros.spin_until(lambda: all(ros.drops().get(k, 0) >= v for k, v in expected.items())
                          and ros.decided().get("empty_cloud") == 1 and node.slam.step_count >= 4, 5.0), ros.drops()
    drops = ros.drops()
    assert {k: drops.get(k) for k in expected} == expected and "empty_cloud" not in drops
    assert drops.get("large_time_step_clipped", 0) >= 1
    assert ros.diagnostics()["dropped_total"] == str(sum(drops.values()))

    # The node keeps publishing finite values.
    assert ros.spin_until(lambda: any(conv.stamp_to_sec(m.header.stamp) == pytest.approx(T0 + 30.6)
                                      for m in ros.received["pose"]), 3.0)
    assert all(finite_pose(m) for m in ros.received["pose"])
    assert ros.spin_until(lambda: ros.received["landmarks"], 3.0)
    columns = decode_message(ros.received["landmarks"][-1], required=("x", "y", "cov_xx"))
    assert all(np.all(np.isfinite(columns[k])) for k in ("x", "y", "cov_xx", "cov_xy", "cov_yy"))
    for marker in ros.received["landmark_markers"][-1].markers:
        assert all(math.isfinite(v) for p in marker.points for v in (p.x, p.y, p.z))


def test_invalid_parameters_are_refused(ros):
    node = ros.start()
    result = node.set_parameters([Parameter("filter.num_particles", value=0)])[0]
    assert not result.successful and "filter.num_particles" in result.reason
    result = node.set_parameters([Parameter("noise.sigma_range", value=0.0)])[0]
    assert not result.successful and "noise.sigma_range" in result.reason and "(0.0, 100.0]" in result.reason
    result = node.set_parameters([Parameter("noise.rho", value=1.0)])[0]
    assert not result.successful and "noise.rho" in result.reason
    result = node.set_parameters([Parameter("motion.model", value="unicycle")])[0]
    assert not result.successful and "motion.model" in result.reason
    result = node.set_parameters([Parameter("motion_source", value="control")])[0]
    assert not result.successful and "read-only" in result.reason
    assert node.get_parameter("filter.num_particles").value == 100

    # A valid change is accepted and used after the next reset.
    assert node.set_parameters([Parameter("filter.num_particles", value=20)])[0].successful
    assert node.slam.config.filter.num_particles == 100
    assert ros.call(Trigger, "reset", Trigger.Request()).success
    assert node.slam.config.filter.num_particles == 20

    # At start-up an invalid value raises an error naming the parameter.
    for name, value in (("noise.rho", 3.0), ("filter.num_particles", -1), ("em.algorithm", "magic")):
        with pytest.raises(ParameterError, match=name.replace(".", r"\.")):
            OnlineEmSlamNode(node_name=f"bad_{name.replace('.', '_')}", context=ros.context,
                             parameter_overrides=[Parameter(name, value=value)])


def test_conversions_pose_covariance_and_quaternions():
    from online_em_slam.core.types import PoseEstimate
    cov = np.array([[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 0.5]])
    msg = conv.pose_to_msg(Header(frame_id="map"), PoseEstimate(1.0, np.array([1.0, 2.0, 3.0]), cov))
    c = msg.pose.covariance
    assert (c[0], c[1], c[5], c[6], c[7], c[11], c[30], c[31], c[35]) == (1.0, 0.1, 0.2, 0.1, 2.0, 0.3, 0.2, 0.3, 0.5)
    assert conv.quaternion_to_yaw(msg.pose.pose.orientation) == pytest.approx(3.0)
    for yaw in np.linspace(-math.pi + 1e-9, math.pi, 13):
        assert conv.quaternion_to_yaw(conv.yaw_to_quaternion(yaw)) == pytest.approx(yaw)
    assert conv.pose_to_msg(Header(), PoseEstimate(1.0, np.array([np.nan, 0.0, 0.0]), cov)) is None
    a, b = np.array([1.0, 2.0, 0.7]), np.array([-0.5, 0.3, -2.0])
    assert np.allclose(conv.pose2d_compose(conv.pose2d_inverse(a), conv.pose2d_compose(a, b)), b)


def test_late_observations_are_reordered_within_input_delay(ros):
    node = ros.start(motion_source="odom", input_delay=0.5)
    for k in range(11):
        ros.odom(T0 + 0.1 * k, 0.1 * k, 0.0, 0.0)
    assert ros.spin_until(lambda: node.inputs_received == 11, 3.0)
    ros.cloud(T0 + 0.7, [5.0], [0.0], [3])          # arrives after odometry up to T0 + 1.0
    ros.cloud(T0 + 0.2, [5.0], [0.0], [3])          # older than the buffer: dropped
    # Everything left in the buffer is processed once the inputs stop.
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 1.0), 3.0)
    assert len(node.slam.landmarks()) == 1
    assert node.all_drops() == {"out_of_order": 1}
