"""What a ROS user reaches for first (issue 11), live: /initialpose relocalises the
robot and keeps the map; a stopped input turns /diagnostics to WARN within 2 s."""
import os
import re
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"

import numpy as np  # noqa: E402
import pytest  # noqa: E402

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from test_node import T0  # noqa: E402

from online_em_slam.ros import conversions as conv  # noqa: E402


def _drive(ros, steps, t0=0.0):
    """Odometry at 20 Hz along x at 1 m/s, a landmark at (10, 0) seen every 0.2 s."""
    for k in range(steps):
        t = t0 + 0.05 * k
        ros.odom(T0 + t, t, 0.0, 0.0)
        if k % 4 == 0:
            ros.cloud(T0 + t, [10.0 - t], [0.0], [1])
        ros.spin_for(0.005)
    return t0 + 0.05 * steps


def _initial_pose(x, y, yaw, frame="map"):
    msg = PoseWithCovarianceStamped(header=Header(frame_id=frame))
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    msg.pose.pose.orientation = conv.yaw_to_quaternion(yaw)
    msg.pose.covariance[0] = msg.pose.covariance[7] = 0.01
    msg.pose.covariance[35] = 1e-4
    return msg


def test_initialpose_moves_the_pose_and_keeps_the_map(ros):
    node = ros.start()
    publisher = ros.tester.create_publisher(PoseWithCovarianceStamped, "/initialpose", 1)
    t = _drive(ros, 40)
    assert ros.spin_until(lambda: len(node.slam.landmarks()) == 1)
    landmark = node.slam.landmarks().positions[0].copy()
    assert ros.spin_until(lambda: publisher.get_subscription_count() > 0)
    publisher.publish(_initial_pose(t + 1.0, 0.5, 0.1))
    assert ros.spin_until(lambda: abs(node.slam.pose().mean[1] - 0.5) < 0.2, timeout=5.0)
    lm = node.slam.landmarks()
    assert len(lm) == 1 and np.allclose(lm.positions[0], landmark)
    publisher.publish(_initial_pose(0.0, 0.0, 0.0, frame="odom"))         # wrong frame: refused
    assert ros.spin_until(lambda: node.all_drops().get("initial_pose_wrong_frame", 0) == 1, timeout=5.0)


def test_estimator_decisions_leave_diagnostics_ok(ros):
    """Empty clouds and readings beyond the sensor's range are valid input the estimator decides
    not to use: counted under decided.*, the status stays OK (ROS-conventions item 3)."""
    ros.start(diagnostics_period=0.2, input_delay=5.0)          # the inputs stop: not silent yet
    t = _drive(ros, 20)
    for k in range(5):
        ros.odom(T0 + t + 0.05 * k, t + 0.05 * k, 0.0, 0.0)
        ros.cloud(T0 + t + 0.05 * k, [] if k % 2 else [1e6], [] if k % 2 else [0.0], [] if k % 2 else [1])
        ros.spin_for(0.02)
    assert ros.spin_until(lambda: ros.decided().get("empty_cloud", 0) >= 2
                          and ros.decided().get("observation_out_of_range", 0) >= 3, timeout=5.0), ros.decided()
    ros.received["diagnostics"].clear()
    assert ros.spin_until(lambda: len(ros.received["diagnostics"]) >= 2, timeout=3.0)
    statuses = [s for m in ros.received["diagnostics"] for s in m.status]
    assert all(s.level == DiagnosticStatus.OK for s in statuses), [s.message for s in statuses]
    assert ros.diagnostics()["dropped_total"] == "0", ros.drops()
    assert int(ros.diagnostics()["decided_total"]) >= 5


def test_a_stopped_input_turns_diagnostics_to_warn_within_two_seconds(ros):
    ros.start(input_delay=0.5, diagnostics_period=0.2)
    _drive(ros, 30)

    def warnings():
        return [s.message for m in ros.received["diagnostics"] for s in m.status
                if s.level == DiagnosticStatus.WARN]

    # Both inputs stopped together; the observations (last sent one odometry period
    # earlier) may be reported first, so wait for the WARN that names odometry.
    ros.received["diagnostics"].clear()
    stopped = time.monotonic()
    assert ros.spin_until(lambda: any("odom for" in w for w in warnings()), timeout=2.0)
    assert time.monotonic() - stopped < 2.0
    assert all("silent inputs" in w for w in warnings())


def test_inputs_that_stop_for_input_timeout_turn_diagnostics_to_error(ros):
    """ROS-conventions item 3: silent for input_delay is WARN, for input_timeout ERROR."""
    ros.start(input_delay=0.3, input_timeout=1.0, diagnostics_period=0.2)
    _drive(ros, 20)
    ros.received["diagnostics"].clear()

    def levels():
        return [(s.level, s.message) for m in ros.received["diagnostics"] for s in m.status]
    assert ros.spin_until(lambda: any(level == DiagnosticStatus.ERROR for level, _ in levels()), timeout=3.0)
    error = next(message for level, message in levels() if level == DiagnosticStatus.ERROR)
    assert re.search(r"no input for \d+ s", error) and "silent inputs" in error
    assert any(level == DiagnosticStatus.WARN for level, _ in levels())      # before the timeout


def test_a_subscribed_topic_that_never_delivers_is_named(ros, capfd):
    """ROS-conventions item 5: with control_topic misspelled, /diagnostics and the log name the
    control topic (resolved) while the observations flow, and the log points at /control."""
    ros.start(motion_source="control", control_topic="contrl", input_delay=0.3, diagnostics_period=0.2)
    for k in range(20):
        ros.control(T0 + 0.05 * k, 1.0, 0.0)
        if k % 4 == 0:
            ros.cloud(T0 + 0.05 * k, [10.0], [0.0], [1])
        ros.spin_for(0.02)

    def named():
        return [s for m in ros.received["diagnostics"] for s in m.status
                if s.level == DiagnosticStatus.WARN and "/contrl (control_topic, 0 publishers)" in s.message]
    assert ros.spin_until(lambda: named(), timeout=3.0)
    message = named()[-1].message
    assert "nothing received on" in message and "/odom (odom_topic, 1 publisher, optional)" in message
    log = capfd.readouterr().err
    assert "nothing received on /contrl (control_topic; 0 publishers)" in log and "/control" in log
