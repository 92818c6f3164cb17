"""map -> odom on /tf as tf2_msgs/TFMessage (REP-105) without tf2_ros.

In a PyPI-wheels environment a wire-compatible tf2_msgs is built from the rosidl wheels
(online_em_slam.messages.tf2_build: `make install`, or the node and the bag tools on first
use after `pip install ".[ros]"`); the node then publishes map -> odom on /tf with the
real tf2_msgs/msg/TFMessage type name and hash.  Without tf2_msgs it keeps the
~/map_to_odom fallback (checked here with a fake node, no rclpy needed).
"""
import math
import sys

import numpy as np
import pytest

#: `ros2 topic info -v /tf` on a real Jazzy install.
TF_MESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
T0 = 1000.0


pytestmark = pytest.mark.usefixtures("no_discovery")     # conftest.py


def _tf2_msgs_importable() -> bool:
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return False
    return TFMessage is not None


def test_tf2_msgs_source_package_is_hidden_from_colcon_and_rosdep():
    from online_em_slam.messages.tf2_build import build
    assert (build.SOURCE_DIR / "COLCON_IGNORE").is_file()     # colcon and catkin_pkg (rosdep) skip it
    assert (build.SOURCE_DIR / "msg" / "TFMessage.msg").read_text().split() == \
        ["geometry_msgs/TransformStamped[]", "transforms"]
    catkin_pkg = pytest.importorskip("catkin_pkg.packages")
    root = build.SOURCE_DIR.parents[3]
    assert [p.name for p in catkin_pkg.find_packages(str(root)).values()] == ["online_em_slam"]


def test_build_command_says_one_line_and_fails_when_it_cannot(monkeypatch, capsys):
    """`online-em-slam-tf2-msgs build` (make install ignores its status): one line, status 1."""
    from online_em_slam.messages.tf2_build import cli, first_use
    monkeypatch.setattr(first_use, "available", lambda: False)
    monkeypatch.setattr(first_use.builder, "missing", lambda prefix: "cmake not found (pip install cmake)")
    monkeypatch.setattr(first_use, "said_unavailable", False)
    monkeypatch.delenv(first_use.SKIP_VARIABLE, raising=False)
    assert cli.main(["build"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("tf2_msgs: not importable and cannot be built here (cmake not found")
    assert "~/map_to_odom" in out[0]
    monkeypatch.setattr(first_use, "available", lambda: True)
    assert cli.main(["build"]) == 0 and cli.main(["check"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "tf2_msgs: already importable: the node publishes map -> odom on /tf", "tf2_msgs importable"]


class _FakeNode:
    def __init__(self):
        self.publishers = []

    def create_publisher(self, kind, topic, qos):
        self.publishers.append((kind.__name__, topic))
        return type("P", (), {"publish": lambda self, msg: None})()


def test_fallback_to_map_to_odom_when_tf2_msgs_is_not_importable(monkeypatch):
    pytest.importorskip("rclpy")
    from online_em_slam.ros.transform_sender import TransformSender
    monkeypatch.setitem(sys.modules, "tf2_ros", None)          # None in sys.modules: ImportError
    monkeypatch.setitem(sys.modules, "tf2_msgs", None)
    monkeypatch.setitem(sys.modules, "tf2_msgs.msg", None)
    node = _FakeNode()
    sender = TransformSender(node)
    assert node.publishers == [("TransformStamped", "~/map_to_odom")]
    assert "~/map_to_odom" in sender.kind


@pytest.mark.skipif(not _tf2_msgs_importable(),
                    reason="tf2_msgs not importable: `online-em-slam-tf2-msgs build` builds it (needs "
                           "cmake and a C compiler; see .venv/build/tf2_msgs.log)")
def test_map_to_odom_on_tf_as_tf2_msgs_tfmessage(ros):
    from online_em_slam.ros import conversions as conv
    node = ros.start(motion_source="odom", **{"initial_pose.x": 1.0, "initial_pose.y": 2.0,
                                              "initial_pose.yaw": 0.5})
    if node.outputs.transform.kind.startswith("tf2_ros"):
        pytest.skip("tf2_ros importable: the broadcaster publishes /tf (real Jazzy install)")
    assert node.outputs.transform.kind == "tf2_msgs/TFMessage on /tf"
    # REP-105: one publisher of map -> odom, on /tf, of the real tf2_msgs/msg/TFMessage type.
    (info,) = ros.node.get_publishers_info_by_topic("/tf")
    assert info.node_name == "online_em_slam"
    assert info.topic_type == "tf2_msgs/msg/TFMessage"
    assert str(info.topic_type_hash) == TF_MESSAGE_HASH
    assert ros.node.get_publishers_info_by_topic("/online_em_slam/map_to_odom") == []

    odom0 = np.array([3.0, -1.0, -0.2])
    for k in range(10):
        ros.odom(T0 + 0.1 * k, odom0[0] + 0.1 * k * math.cos(odom0[2]), odom0[1] + 0.1 * k * math.sin(odom0[2]),
                 odom0[2])
    assert ros.spin_until(lambda: len(ros.received["map_to_odom"]) >= 5, 10.0)
    tf = ros.received["map_to_odom"][-1]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "odom")
    expected = conv.pose2d_compose(np.array([1.0, 2.0, 0.5]), conv.pose2d_inverse(odom0))
    got = (tf.transform.translation.x, tf.transform.translation.y, conv.quaternion_to_yaw(tf.transform.rotation))
    assert np.allclose(got, expected, atol=0.05), (got, expected)
