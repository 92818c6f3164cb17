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
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

DOMAIN_ID = 20 + os.getpid() % 40
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
    out = subprocess.run(_tool("topic_tool", "echo", POSE_TOPIC, "--once", "--timeout", "20"),
                         env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert "frame_id: 'map'" in text and "sec: 12" in text and "nanosec: 500000000" in text
    assert "x: 3.25" in text and "y: -1.5" in text and text.rstrip().endswith("---")
    assert "covariance: [0.25, 0.0" in text
    listing = subprocess.run(_tool("topic_tool", "list", "-t", "--spin-time", "3"),
                             env=env, capture_output=True, text=True, timeout=60)
    assert f"{POSE_TOPIC} [geometry_msgs/msg/PoseWithCovarianceStamped]" in listing.stdout


def test_topic_hz_and_missing_topic(ros):
    from std_msgs.msg import String
    _, node, env = ros
    pub = node.create_publisher(String, "/chatter", 10)
    proc = subprocess.Popen(_tool("topic_tool", "hz", "/chatter", "--duration", "2.5", "--timeout", "20"),
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    while proc.poll() is None and time.monotonic() < deadline:
        pub.publish(String(data="x"))
        time.sleep(0.02)                                 # about 50 Hz (sleep granularity)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    rates = [float(line.split(":")[1]) for line in out.splitlines() if line.startswith("average rate")]
    assert rates and 20 < rates[-1] < 60
    missing = subprocess.run(_tool("topic_tool", "echo", "/nobody", "--once", "--timeout", "0.5"),
                             env=env, capture_output=True, text=True, timeout=60)
    assert missing.returncode == 1 and "no publisher" in missing.stderr


def test_yaml_formatting_of_arrays_and_nested_messages():
    from geometry_msgs.msg import Pose, PoseArray

    from online_em_slam.topic_tool import MAX_ARRAY, message_to_yaml
    msg = PoseArray(poses=[Pose() for _ in range(MAX_ARRAY + 3)])
    msg.poses[0].position.x = 1.5
    lines = message_to_yaml(msg)
    assert "poses:" in lines and "- position:" in lines and "    x: 1.5" in lines
    assert lines[-1] == f"- '... {MAX_ARRAY + 3} elements'"
    assert len(message_to_yaml(msg, full_arrays=True)) > len(lines)
