"""online-em-slam-topic, online-em-slam-record and online-em-slam evaluate with live rclpy.

Each tool runs as a separate process; the test process publishes.  Discovery must
stay on between processes, so every test gets this run's own ROS_DOMAIN_ID
(set through monkeypatch, never for the whole session: other modules' in-process
tests rely on their own settings).
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from ros_domain import claim  # noqa: E402

DOMAIN_ID = claim()
POSE_TOPIC = "/online_em_slam/pose"
LANDMARKS_TOPIC = "/online_em_slam/landmarks"


@pytest.fixture
def ros(monkeypatch):
    """A context on this run's domain with discovery on; yields (context, node, env for tools)."""
    from rclpy.context import Context
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node("tools_test", context=context)
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        yield context, node, env
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def _latched():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _pose_msg(t: float, x: float, y: float, yaw: float):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = "map"
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t - int(t)) * 1e9))
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    msg.pose.covariance[0] = msg.pose.covariance[7] = 0.25
    return msg


def _tool(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", f"online_em_slam.{module}", *args]


def test_topic_echo_prints_a_pose(ros):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    _, node, env = ros
    pub = node.create_publisher(PoseWithCovarianceStamped, POSE_TOPIC, _latched())
    pub.publish(_pose_msg(12.5, 3.25, -1.5, 0.3))       # latched: echo gets it on joining
    out = subprocess.run(_tool("bag.topic_tool", "echo", POSE_TOPIC, "--once", "--timeout", "20"),
                         env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert "frame_id: 'map'" in text and "sec: 12" in text and "nanosec: 500000000" in text
    assert "x: 3.25" in text and "y: -1.5" in text and text.rstrip().endswith("---")
    assert "covariance: [0.25, 0.0" in text
    # Discovery between processes takes a variable time on a loaded machine: a listing
    # may miss a topic that exists, so list again (a few times) before concluding.
    wanted = f"{POSE_TOPIC} [geometry_msgs/msg/PoseWithCovarianceStamped]"
    for _ in range(4):
        listing = subprocess.run(_tool("bag.topic_tool", "list", "-t", "--spin-time", "3"),
                                 env=env, capture_output=True, text=True, timeout=60)
        if wanted in listing.stdout:
            break
    assert wanted in listing.stdout


def test_topic_hz_and_missing_topic(ros):
    from std_msgs.msg import String
    _, node, env = ros
    pub = node.create_publisher(String, "/chatter", 10)
    proc = subprocess.Popen(_tool("bag.topic_tool", "hz", "/chatter", "--duration", "2.5", "--timeout", "20"),
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    while proc.poll() is None and time.monotonic() < deadline:
        pub.publish(String(data="x"))
        time.sleep(0.02)                                 # about 50 Hz (sleep granularity)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    rates = [float(line.split(":")[1]) for line in out.splitlines() if line.startswith("average rate")]
    assert rates and 20 < rates[-1] < 60
    missing = subprocess.run(_tool("bag.topic_tool", "echo", "/nobody", "--once", "--timeout", "0.5"),
                             env=env, capture_output=True, text=True, timeout=60)
    assert missing.returncode == 1 and "no publisher" in missing.stderr


def test_yaml_formatting_of_arrays_and_nested_messages():
    from geometry_msgs.msg import Pose, PoseArray

    from online_em_slam.bag.topic_tool import MAX_ARRAY, message_to_yaml
    msg = PoseArray(poses=[Pose() for _ in range(MAX_ARRAY + 3)])
    msg.poses[0].position.x = 1.5
    lines = message_to_yaml(msg)
    assert "poses:" in lines and "- position:" in lines and "    x: 1.5" in lines
    assert lines[-1] == f"- '... {MAX_ARRAY + 3} elements'"
    assert len(message_to_yaml(msg, full_arrays=True)) > len(lines)


# --------------------------------------------------------------------------- record + evaluate

OFFSET = (2.0, 0.5)                                     # base_link -> laser in the truth bag


def _truth_track():
    """Base poses (n, 4: t, x, y, yaw) on a circle in the GPS frame, 20 Hz for 10 s."""
    t = 100.0 + np.arange(200) * 0.05
    a = 0.3 * (t - t[0])
    return np.column_stack([t, 5 + 20 * np.sin(a), -3 + 20 * (1 - np.cos(a)), a])


def _write_truth_bag(path, track, landmarks):
    from online_em_slam.bag.bagio import write_bag
    from online_em_slam.messages.cloud import encode
    from online_em_slam.offline.evaluation import sensor_points
    from online_em_slam.bag.bagio import jazzy_typestore

    ts = jazzy_typestore()
    T = ts.types

    def header(t, frame):
        sec = int(t)
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    laser = T["geometry_msgs/msg/TransformStamped"](header=header(track[0, 0], "base_link"), child_frame_id="laser",
                                                    transform=T["geometry_msgs/msg/Transform"](
                                                        translation=V3(x=OFFSET[0], y=OFFSET[1], z=0.0),
                                                        rotation=Q(x=0.0, y=0.0, z=0.0, w=1.0)))
    specs, step, data = encode({"x": landmarks[:, 0], "y": landmarks[:, 1], "z": np.zeros(len(landmarks))},
                               layout=(("x", "f4"), ("y", "f4"), ("z", "f4")))
    cloud = T["sensor_msgs/msg/PointCloud2"](
        header=header(track[0, 0], "gps"), height=1, width=len(landmarks),
        fields=[T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                for f in specs], is_bigendian=False, point_step=step, row_step=step * len(landmarks),
        data=np.frombuffer(data, dtype=np.uint8).copy(), is_dense=True)
    events = [(track[0, 0], "/tf_static", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](transforms=[laser])),
              (track[0, 0], "/ground_truth/landmarks", "sensor_msgs/msg/PointCloud2", cloud)]
    # Odometry starts at (0, 0, 0): the truth track seen from its first pose.
    from online_em_slam.offline.evaluate_recording import compose, inverse
    odom = compose(inverse(track[0, 1:4]), track[:, 1:4])
    gps = sensor_points(track[:, 1:4], OFFSET)
    for k, (t, x, y, yaw) in enumerate(np.column_stack([track[:, 0], odom])):
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                                           orientation=Q(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))
        events.append((t, "/odom", "nav_msgs/msg/Odometry", T["nav_msgs/msg/Odometry"](
            header=header(t, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                linear=V3(x=0.0, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36)))))
        if k % 2 == 0:
            events.append((t, "/ground_truth/position", "geometry_msgs/msg/PointStamped",
                           T["geometry_msgs/msg/PointStamped"](header=header(t, "gps"), point=T[
                               "geometry_msgs/msg/Point"](x=gps[k, 0], y=gps[k, 1], z=0.0))))
    write_bag(path, ((int(round(t * 1e9)), topic, msgtype, msg) for t, topic, msgtype, msg in events), ts)


def _landmark_cloud(xy, n_obs):
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    from online_em_slam.messages.cloud import LANDMARK_FIELDS, build_message
    cols = {"x": xy[:, 0], "y": xy[:, 1], "z": np.zeros(len(xy)), "id": np.arange(len(xy)), "n_obs": n_obs}
    return build_message(PointCloud2, PointField, Header(frame_id="map"), cols, LANDMARK_FIELDS)


def _finish(proc, timeout: float = 30.0):
    """communicate() after a SIGINT; a process that does not exit by then is killed."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate(timeout=10)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _wait(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.05)
    return predicate()


def test_record_then_evaluate_a_node_run(ros, tmp_path):
    """Poses and a map published like the node's (map frame = its start pose, initial pose 0)
    are recorded by online-em-slam-record; evaluate brings them into the GPS frame and
    measures exactly the errors put in: 0.1 m lateral on the track, 0.2 m on each beacon."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import PointCloud2

    from online_em_slam.offline import cli
    from online_em_slam.offline.evaluate_recording import compose, inverse
    from online_em_slam.offline.tum import read_tum

    _, node, env = ros
    track = _truth_track()
    truth_landmarks = np.array([[0.0, 10.0], [15.0, 25.0], [30.0, 5.0], [-5.0, 30.0], [20.0, 15.0]])
    _write_truth_bag(tmp_path / "truth", track, truth_landmarks)
    to_map = inverse(track[0, 1:4])                     # node map frame = the start pose
    estimate = compose(to_map, track[:, 1:4])
    estimate[:, 1] += 0.1 * np.cos(estimate[:, 2])      # 0.1 m to the left of the true base pose
    estimate[:, 0] -= 0.1 * np.sin(estimate[:, 2])
    lm_map = compose(to_map, np.column_stack([truth_landmarks, np.zeros(5)]))[:, :2]
    lm_map += 0.2 * np.array([1.0, 0.0])                # 0.2 m along the map x axis

    deep_latched = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pose_pub = node.create_publisher(PoseWithCovarianceStamped, POSE_TOPIC, deep_latched)
    map_pub = node.create_publisher(PointCloud2, LANDMARKS_TOPIC, deep_latched)
    out = tmp_path / "recorded"
    proc = subprocess.Popen(_tool("bag.record", str(out), "--topics", POSE_TOPIC, LANDMARKS_TOPIC),
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert _wait(lambda: pose_pub.get_subscription_count() and map_pub.get_subscription_count(), 30)
        for (t, *_), pose in zip(track, estimate):
            pose_pub.publish(_pose_msg(t, *pose))
        map_pub.publish(_landmark_cloud(lm_map, np.array([5, 5, 5, 5, 1])))
        assert _wait(lambda: pose_pub.wait_for_all_acked(rclpy.duration.Duration(seconds=0.1))
                     and map_pub.wait_for_all_acked(rclpy.duration.Duration(seconds=0.1)), 20)
        time.sleep(0.3)
    finally:
        proc.send_signal(signal.SIGINT)                  # the bag is closed on Ctrl-C
        stdout, stderr = _finish(proc)
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["recorded"] == {POSE_TOPIC: 200, LANDMARKS_TOPIC: 1}

    result = tmp_path / "eval"
    assert cli.main(["evaluate", str(out), "--truth", str(tmp_path / "truth"), "--output", str(result),
                     "--no-plot"]) == 0
    metrics = json.loads((result / "metrics.json").read_text())
    assert metrics["sensor_offset"] == list(OFFSET)      # from the truth bag's /tf_static
    lm = metrics["landmarks"]
    # The fifth beacon has one observation: not confirmed, so missed.
    assert (lm["n_matched"], lm["n_spurious"], lm["n_true"]) == (4, 0, 5)
    assert lm["rmse"] == pytest.approx(0.2, abs=1e-3)
    assert metrics["trajectory"]["rmse"] == pytest.approx(0.1, abs=1e-3)
    assert metrics["trajectory"]["n_compared"] == 100
    tum = read_tum(result / "trajectory.tum")
    assert tum.shape == (200, 8)
    np.testing.assert_allclose(tum[:, 0], track[:, 0], atol=1e-6)
    assert read_tum(result / "ground_truth.tum").shape == (100, 8)


def test_record_and_evaluate_car_park_match_run(ros, tmp_path):
    """The Car Park bag replayed (20x) into the node in its own process, recorded by
    online-em-slam-record, scored by evaluate: the beacon RMSE of run on the same bag
    within Monte Carlo noise (the node starts at (0, 0, 0): evaluate carries its map
    frame into the GPS frame; run starts at the GPS-derived pose)."""
    from pathlib import Path

    from online_em_slam.offline import cli
    from online_em_slam.bag.bagio import read_bag
    from online_em_slam.datasets.kth.convert import convert

    context, node, env = ros
    params = str(Path(__file__).resolve().parent.parent / "config" / "hand_tuned" / "car_park.yaml")
    bag = tmp_path / "car_park"
    convert("car_park", bag, progress=False)
    assert cli.main(["run", str(bag), "--params", params, "--seed", "0", "--output", str(tmp_path / "run"),
                     "--no-plot"]) == 0
    run = json.loads((tmp_path / "run" / "metrics.json").read_text())

    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import PointCloud2

    last_scan = max(stamp for _, stamp, _ in read_bag(bag, ["/landmark_observations"]))
    maps = []
    node.create_subscription(PointCloud2, LANDMARKS_TOPIC, maps.append, _latched())
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    procs = {}
    try:
        procs["record"] = subprocess.Popen(_tool("bag.record", str(tmp_path / "rec"), "--no-inputs", "--quiet"),
                                           env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs["node"] = subprocess.Popen(
            _tool("ros.node", "--ros-args", "--params-file", params, "-p", "filter.seed:=0",
                  "-p", "publish_particles:=false", "--log-level", "error"),
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        replay = subprocess.run(_tool("bag.replay", str(bag), "--rate", "20", "--topics", "/control", "/odom",
                                      "/landmark_observations", "--wait-subscribers", "/control:1", "/odom:1",
                                      "/landmark_observations:1", "--wait-timeout", "30", "--quiet"),
                                env=env, capture_output=True, text=True, timeout=120)
        assert replay.returncode == 0, replay.stderr
        # The node may lag the replay: wait for a map that includes the last observation.
        assert _wait(lambda: maps and _stamp(maps[-1]) >= last_scan - 1e-6, 60), "no final map"
        time.sleep(2.0)                                   # the recorder has it too, even when loaded
    finally:
        for name in ("record", "node"):
            if name in procs and procs[name].poll() is None:
                procs[name].send_signal(signal.SIGINT)
        outputs = {name: _finish(p) for name, p in procs.items()}
        executor.shutdown(timeout_sec=1.0)
    assert procs["record"].returncode == 0, outputs["record"][1]
    recorded = json.loads(outputs["record"][0].strip().splitlines()[-1])["recorded"]
    assert recorded["/online_em_slam/pose"] > 300 and recorded["/online_em_slam/landmarks"] >= 1

    assert cli.main(["evaluate", str(tmp_path / "rec"), "--truth", str(bag), "--params", params,
                     "--output", str(tmp_path / "eval"), "--no-plot"]) == 0
    live = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    # The live node's map may miss one beacon of the offline run's 15: at 20x the node takes its
    # inputs as they arrive, and once in four clean-clone CI runs (2026-12-02) a beacon ended just
    # outside the match gate (14/15, none spurious); the offline run is deterministic.
    assert run["landmarks"]["n_matched"] == 15
    assert live["landmarks"]["n_matched"] >= 14, (live["landmarks"], outputs["node"][1][-2000:])
    assert live["landmarks"]["n_spurious"] <= 1
    assert abs(live["landmarks"]["rmse"] - run["landmarks"]["rmse"]) < 0.1
    # ~/pose is map->odom from the estimator's last update composed with the newest odometry:
    # at 20x a second of estimator lag is 20 s of bag time extrapolated on odometry alone
    # (measured 0.41-1.7 m against the runner's 0.25 m, depending on the machine's load), so
    # only the map is compared; docs/RESULTS.md compares trajectories at replay rate 5.
    assert math.isfinite(live["trajectory"]["rmse"])


def test_record_under_sim_time_writes_start_up_messages_at_the_first_clock():
    """ROS-conventions item 6: started before the replay, the recorder gets the node's latched
    start-up messages at sim time 0; they wait for the first /clock and are written at it, so
    they come first in the bag (not at a wall-clock stamp after the whole run)."""
    from types import SimpleNamespace

    from online_em_slam.bag.record import Recorder

    clock = {"ns": 0}
    node = SimpleNamespace(get_clock=lambda: SimpleNamespace(now=lambda: SimpleNamespace(nanoseconds=clock["ns"])))
    written = []
    writer = SimpleNamespace(write=lambda conn, stamp, raw: written.append((conn, stamp, raw)))
    recorder = Recorder(node, writer, ["/online_em_slam/landmarks"], log=lambda *_: None)
    recorder.counts = {"latched": 0, "pose": 0}
    recorder.store("c1", "latched", b"start-up")
    assert recorder.holding and written == []
    clock["ns"] = 5_000_000_000                    # the first /clock
    recorder.store("c2", "pose", b"first")
    assert written == [("c1", 5_000_000_000, b"start-up"), ("c2", 5_000_000_000, b"first")]
    assert recorder.counts == {"latched": 1, "pose": 1} and not recorder.holding
