"""online-em-slam-replay publishes every message of a bag to a subscriber in another process."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from ros_domain import claim

# Multi-process tests: discovery must stay on (docs/ROS.md), on a domain of this run's own.
DOMAIN_ID = str(claim())

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

N_CONTROL = 400
N_CLOUDS = 40


def write_small_bag(path):
    """/control at 200 Hz (2 s) and /landmark_observations at 20 Hz, plus /tf_static."""
    from online_em_slam.bag.bagio import write_bag
    from online_em_slam.messages.cloud import OBSERVATION_FIELDS, encode
    from online_em_slam.datasets.kth.beacons import observation_columns
    from online_em_slam.bag.bagio import jazzy_typestore

    ts = jazzy_typestore()
    T = ts.types
    rng = np.random.default_rng(7)

    def header(ns, frame):
        sec, nsec = divmod(ns, 1_000_000_000)
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                        frame_id=frame)

    V3 = T["geometry_msgs/msg/Vector3"]
    events = []
    for k in range(N_CONTROL):
        ns = 10_000_000_000 + k * 5_000_000
        msg = T["geometry_msgs/msg/TwistStamped"](
            header=header(ns, "base_link"),
            twist=T["geometry_msgs/msg/Twist"](linear=V3(x=float(k), y=0.0, z=0.0),
                                               angular=V3(x=0.0, y=0.0, z=0.01 * k)))
        events.append((ns, 1, "/control", "geometry_msgs/msg/TwistStamped", msg))
    for k in range(N_CLOUDS):
        ns = 10_000_000_000 + k * 50_000_000 + 1
        n = int(rng.integers(0, 5))
        specs, step, data = encode(observation_columns(rng.uniform(1, 30, n), rng.uniform(-1.5, 1.5, n)),
                                   layout=OBSERVATION_FIELDS)
        fields = [T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype,
                                                  count=f.count) for f in specs]
        msg = T["sensor_msgs/msg/PointCloud2"](header=header(ns, "laser"), height=1, width=n, fields=fields,
                                               is_bigendian=False, point_step=step, row_step=step * n,
                                               data=np.frombuffer(data, dtype=np.uint8).copy(), is_dense=True)
        events.append((ns, 2, "/landmark_observations", "sensor_msgs/msg/PointCloud2", msg))
    tf = T["geometry_msgs/msg/TransformStamped"](
        header=header(10_000_000_000, "base_link"), child_frame_id="laser",
        transform=T["geometry_msgs/msg/Transform"](translation=V3(x=3.78, y=0.5, z=0.0),
                                                   rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0,
                                                                                              z=0.0, w=1.0)))
    events.append((10_000_000_000, 0, "/tf_static", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](
        transforms=[tf])))
    events.sort(key=lambda e: (e[0], e[1]))
    write_bag(path, ((ns, topic, msgtype, msg) for ns, _, topic, msgtype, msg in events), ts)


def _tf2_available() -> bool:
    try:
        import tf2_msgs.msg
        return tf2_msgs.msg.TFMessage is not None
    except ImportError:
        return False


def test_message_class_resolution():
    from online_em_slam.bag.replay import message_class, parse_wait
    from sensor_msgs.msg import PointCloud2
    assert message_class("sensor_msgs/msg/PointCloud2") is PointCloud2
    assert message_class("sensor_msgs/PointCloud2") is PointCloud2
    with pytest.raises(ValueError):
        message_class("nonsense")
    assert parse_wait(["/a:2", "/b"]) == {"/a": 2, "/b": 1}


@pytest.fixture
def discovery(monkeypatch) -> dict:
    """Discovery on between this process and the replay's, on this run's own domain (set per
    test: the in-process tests of other modules run without discovery); the replay's env."""
    monkeypatch.setenv("ROS_DOMAIN_ID", DOMAIN_ID)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return dict(os.environ)


def test_replay_delivers_every_message(tmp_path, discovery):
    from geometry_msgs.msg import TwistStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2

    from online_em_slam.messages.cloud import decode_message

    bag = tmp_path / "small"
    write_small_bag(bag)

    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("replay_test_sink", context=context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        controls, clouds, clocks = [], [], []
        node.create_subscription(TwistStamped, "/control", controls.append, qos)
        node.create_subscription(PointCloud2, "/landmark_observations", clouds.append, qos)
        node.create_subscription(Clock, "/clock", clocks.append, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        env = discovery
        cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", "0", "--clock",
               "--wait-subscribers", "/control:1", "/landmark_observations:1", "/clock:1",
               "--wait-timeout", "15", "--quiet"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        deadline = time.monotonic() + 25
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if len(controls) >= N_CONTROL and len(clouds) >= N_CLOUDS and proc.poll() is not None:
                break
        # drain anything still queued
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
        out, err = proc.communicate(timeout=10)
    finally:
        if "proc" in locals() and proc.poll() is None:
            proc.kill()
        rclpy.shutdown(context=context)

    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["published"]["/control"] == N_CONTROL
    assert summary["published"]["/landmark_observations"] == N_CLOUDS
    if _tf2_available():
        assert summary["published"]["/tf_static"] == 1
    else:
        assert "/tf_static" in summary["skipped_topics"]

    assert len(controls) == N_CONTROL and len(clouds) == N_CLOUDS
    assert [m.twist.linear.x for m in controls] == [float(k) for k in range(N_CONTROL)]
    assert controls[7].header.stamp.sec == 10 and controls[7].header.stamp.nanosec == 35_000_000
    cols = decode_message(clouds[3], required=["range", "bearing", "id"])
    assert np.all(cols["id"] == -1)
    assert len(clocks) >= 1 and clocks[0].clock.sec == 10


def test_beacon_node_publishes_observations():
    """BeaconNode: LaserScan on `scan` -> PointCloud2 on `landmark_observations`, same header."""
    from sensor_msgs.msg import LaserScan, PointCloud2

    from online_em_slam.messages.cloud import decode_message
    from online_em_slam.datasets.kth.beacon_node import BeaconNode
    from online_em_slam.datasets.kth.beacons import extract_beacons
    from online_em_slam.datasets.kth.datasets import load_car_park

    cp = load_car_park()
    sc = cp.scans
    k = next(i for i in range(len(sc))
             if len(extract_beacons(sc.ranges[i], sc.intensities[i], sc.angle_min, sc.angle_increment)) >= 2)
    context = Context()
    rclpy.init(context=context)
    try:
        node = BeaconNode(context=context)
        sink = rclpy.create_node("beacon_sink", context=context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        got = []
        sink.create_subscription(PointCloud2, "landmark_observations", got.append, qos)
        pub = sink.create_publisher(LaserScan, "scan", qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.add_node(sink)
        scan = LaserScan()
        scan.header.frame_id = "laser"
        scan.header.stamp.sec, scan.header.stamp.nanosec = 123, 456
        scan.angle_min, scan.angle_increment = -np.pi / 2, np.deg2rad(0.5)
        scan.angle_max = np.pi / 2
        scan.range_min, scan.range_max = 0.0, 81.9
        r = cp.scans.ranges[k].astype(np.float32)
        r[cp.scans.ranges[k] >= 81.9] = np.inf
        scan.ranges = r.tolist()
        scan.intensities = cp.scans.intensities[k].astype(np.float32).tolist()
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:
            if pub.get_subscription_count() > 0:
                pub.publish(scan)
            executor.spin_once(timeout_sec=0.05)
            executor.spin_once(timeout_sec=0.05)
    finally:
        rclpy.shutdown(context=context)
    assert got, "no observation cloud received"
    msg = got[0]
    assert msg.header.frame_id == "laser" and (msg.header.stamp.sec, msg.header.stamp.nanosec) == (123, 456)
    cols = decode_message(msg, required=["range", "bearing", "id", "range_std"])
    ref = extract_beacons(cp.scans.ranges[k], cp.scans.intensities[k], -np.pi / 2, np.deg2rad(0.5))
    assert len(ref) >= 2
    np.testing.assert_allclose(cols["range"], ref.range, rtol=1e-5)
    np.testing.assert_allclose(cols["bearing"], ref.bearing, atol=1e-5)
    assert np.all(cols["id"] == -1) and np.all(cols["range_std"] == 0)


def test_replay_of_car_park_into_a_live_node_loses_nothing(tmp_path, discovery):
    """The converted Car Park bag replayed (another process, rate 20) into the SLAM node:
    every input reaches the node, none is dropped, and the beacon map is right."""
    from sensor_msgs.msg import PointCloud2

    from online_em_slam.offline.runner import choose_initial_pose, read_inputs
    from online_em_slam.offline.evaluation import landmark_metrics
    from online_em_slam.datasets.kth.convert import convert
    from online_em_slam.parameters.yaml_file import config_from_params, load_params
    from online_em_slam.messages.cloud import decode_message
    from online_em_slam.ros.node import OnlineEmSlamNode
    from rclpy.parameter import Parameter

    bag = tmp_path / "car_park"
    counts = convert("car_park", bag, progress=False)
    params_file = os.path.join(os.path.dirname(__file__), "..", "config", "hand_tuned", "car_park.yaml")
    values = load_params(params_file)
    config, settings = config_from_params(values)
    inputs = read_inputs(bag, settings)
    start = choose_initial_pose("gps", inputs, config, settings, values)

    overrides = [Parameter(name, value=value) for name, value in values.items()]
    overrides += [Parameter("initial_pose.x", value=start.x), Parameter("initial_pose.y", value=start.y),
                  Parameter("initial_pose.yaw", value=start.yaw), Parameter("filter.seed", value=0),
                  Parameter("publish_particles", value=False)]
    context = Context()
    rclpy.init(context=context)
    try:
        node = OnlineEmSlamNode(context=context, parameter_overrides=overrides)
        sink = rclpy.create_node("map_sink", context=context)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        maps = []
        sink.create_subscription(PointCloud2, "/online_em_slam/landmarks", maps.append, latched)
        # The events executor keeps up with a 20x replay in one process (about 3x the
        # single-threaded executor's message rate).
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor(context=context)
        executor.add_node(node)
        executor.add_node(sink)
        env = discovery
        cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", "20",
               "--topics", "/control", "/odom", "/landmark_observations",
               "--wait-subscribers", "/control:1", "/odom:1", "/landmark_observations:1",
               "--wait-timeout", "15", "--quiet"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        expected = counts["/control"] + counts["/odom"] + counts["/landmark_observations"]
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
            if proc.poll() is not None and node.inputs_received >= expected - node.all_drops().get("empty_cloud", 0):
                break
        end = time.monotonic() + 3.0          # let the buffer drain and the map timer fire
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
        out, err = proc.communicate(timeout=10)
        drops = node.all_drops()
        received = node.inputs_received
    finally:
        if "proc" in locals() and proc.poll() is None:
            proc.kill()
        rclpy.shutdown(context=context)

    assert proc.returncode == 0, err
    published = json.loads(out.strip().splitlines()[-1])["published"]
    assert sum(published.values()) == expected
    assert received + drops.get("empty_cloud", 0) == expected, drops
    lost = {k: v for k, v in drops.items() if k not in ("empty_cloud", "ambiguous_association",
                                                        "merged_new_landmark")}
    assert not lost, lost
    assert maps, "no landmark map received"
    cols = decode_message(maps[-1], required=["x", "y", "n_obs"])
    confirmed = cols["n_obs"] >= config.association.confirm_observations
    positions = np.stack([cols["x"], cols["y"]], axis=1)[confirmed].astype(float)
    metrics = landmark_metrics(positions, inputs.landmarks, gate=2.0)
    assert metrics.n_matched == 15 and metrics.n_spurious <= 2 and metrics.rmse < 0.5


def test_a_replay_stopped_by_sigint_while_publishing_reports_valid_json(tmp_path):
    """ROS-conventions item 9: Ctrl-C in a script ends the replay with status 130, no traceback,
    and a summary line that strict JSON reads (the wall time so far, not NaN).  The signal is
    sent once the replay reports publishing (its progress line), not after a fixed delay."""
    import signal
    import threading

    bag = tmp_path / "small"
    write_small_bag(bag)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF", ROS_DOMAIN_ID=str(claim()))
    proc = subprocess.Popen([sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", "0.2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines, publishing = [], threading.Event()

    def read_stderr():
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("replay: ") and " messages, bag time " in line:
                publishing.set()
    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    assert publishing.wait(60.0), "".join(lines)
    proc.send_signal(signal.SIGINT)
    out = proc.stdout.read()
    proc.wait(timeout=30)
    reader.join(timeout=5)
    err = "".join(lines)
    assert proc.returncode == 130 and "Traceback" not in err, err

    def no_constants(name):
        raise ValueError(f"{name} is not JSON")
    summary = json.loads(out.strip().splitlines()[-1], parse_constant=no_constants)
    assert summary["interrupted"] and summary["wall_seconds"] > 0
