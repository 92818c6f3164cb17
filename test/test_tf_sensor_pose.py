"""The sensor pose from TF (tf2_ros, a real Jazzy install) and the input frame checks.

There is no tf2_ros in the wheels-only venv: a small fake ``tf2_ros`` module (a
Buffer answering from a table, a TransformListener that does nothing, no
TransformBroadcaster) is put in sys.modules before the node is made.
"""
import math
import sys
import types

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import TransformStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from online_em_slam.core import Observations  # noqa: E402
from online_em_slam.core.config import SensorConfig  # noqa: E402
from online_em_slam.ros import conversions as conv  # noqa: E402
from online_em_slam.parameters.specs import NodeSettings  # noqa: E402
from online_em_slam.ros.tf import SensorFrames, reexpress  # noqa: E402

T0 = 1000.0


pytestmark = pytest.mark.usefixtures("no_discovery")     # conftest.py


def fake_tf2_ros(transforms: dict) -> types.ModuleType:
    """tf2_ros with a Buffer that knows ``transforms[(target, source)] = (x, y, yaw)``."""
    module = types.ModuleType("tf2_ros")

    class TransformException(Exception):
        pass

    class Buffer:
        def __init__(self, *args, **kwargs):
            self.lookups = []

        def lookup_transform(self, target, source, time, timeout=None):
            self.lookups.append((target, source, time.nanoseconds))
            if (target, source) not in transforms:
                raise TransformException(f"{source} -> {target} unknown")
            x, y, yaw = transforms[(target, source)]
            t = TransformStamped()
            t.header.frame_id, t.child_frame_id = target, source
            t.transform.translation.x, t.transform.translation.y = x, y
            t.transform.rotation = conv.yaw_to_quaternion(yaw)
            return t

    class TransformListener:
        def __init__(self, buffer, node, *, spin_thread=False, **kwargs):
            assert not spin_thread           # callbacks run in the node's executor
            self.buffer, self.node = buffer, node

    module.TransformException, module.Buffer, module.TransformListener = TransformException, Buffer, TransformListener
    return module


class _Node:
    def get_logger(self):
        return self

    def warning(self, message):
        self.warnings.append(message)

    warnings: list


def _frames(monkeypatch, transforms, tf2_ros=True):
    monkeypatch.setitem(sys.modules, "tf2_ros", fake_tf2_ros(transforms) if tf2_ros else None)
    node = _Node()
    node.warnings = []
    return SensorFrames(node), node


SETTINGS = NodeSettings(sensor_frame="laser")


def test_reexpress_places_the_points_of_the_cloud_frame_in_the_sensor_frame():
    obs = Observations([2.0, 1.0], [0.0, math.pi / 2], [3, 4], range_std=[0.1, 0.2])
    out = reexpress(obs, (1.0, 0.5, math.pi / 2))
    points = np.column_stack([out.ranges * np.cos(out.bearings), out.ranges * np.sin(out.bearings)])
    assert points == pytest.approx(np.array([[1.0, 2.5], [0.0, 0.5]]))
    assert list(out.ids) == [3, 4] and list(out.range_std) == [0.1, 0.2]
    assert reexpress(obs, (0.0, 0.0, 2 * math.pi)) is obs          # same mount: untouched


def test_sensor_pose_from_tf_overrides_the_parameters(monkeypatch):
    frames, node = _frames(monkeypatch, {("base_link", "laser"): (3.78, 0.5, 0.0)})
    assert frames.uses_tf
    obs = Observations([10.0], [0.0])
    # The parameters say the same mount: nothing to do.
    same = SensorConfig(offset_x=3.78, offset_y=0.5)
    assert frames.observations("laser", T0, obs, SETTINGS, same) is obs
    # The parameters say (0, 0, 0): TF wins, the point is 3.78 m further and 0.5 m left.
    out = frames.observations("laser", T0, obs, SETTINGS, SensorConfig())
    assert (out.ranges[0] * math.cos(out.bearings[0]), out.ranges[0] * math.sin(out.bearings[0])) == \
        pytest.approx((13.78, 0.5))
    assert frames.placed_by_tf == 2 and frames.tf_failures == 0
    assert frames._buffer.lookups[0] == ("base_link", "laser", int(T0 * 1e9))   # at the cloud's stamp
    assert len(node.warnings) == 1 and "differs from sensor.offset_*" in node.warnings[0]
    assert not frames.unexpected_frames


def test_a_cloud_in_the_base_frame_is_placed_through_tf(monkeypatch):
    frames, _ = _frames(monkeypatch, {("base_link", "base_link"): (0.0, 0.0, 0.0)})
    out = frames.observations("base_link", T0, Observations([5.0], [0.0]), SETTINGS,
                              SensorConfig(offset_x=1.0))
    assert (out.ranges[0], out.bearings[0]) == pytest.approx((4.0, 0.0))    # 1 m behind the sensor's origin


def test_lookup_failure_falls_back_to_the_parameters_and_counts_unknown_frames(monkeypatch):
    frames, node = _frames(monkeypatch, {})
    obs = Observations([10.0], [0.0])
    for _ in range(3):
        assert frames.observations("laser", T0, obs, SETTINGS, SensorConfig()) is obs      # configured frame
        assert frames.observations("camera", T0, obs, SETTINGS, SensorConfig()) is obs     # neither: counted
    assert frames.observations("map", T0, obs, SETTINGS, SensorConfig()) is obs            # never looked up
    assert frames.unexpected_frames == {"camera": 3, "map": 1}
    assert frames.tf_failures == 6 and frames.placed_by_tf == 0
    assert len(node.warnings) == 2 and "nor resolvable through TF" in node.warnings[0]     # once per frame
    assert frames.diagnostics() == {"unexpected_frame.camera": 3, "unexpected_frame.map": 1,
                                    "sensor_pose_from_tf": 0, "sensor_pose_tf_failures": 6}


def test_without_tf2_ros_the_parameters_place_the_sensor(monkeypatch):
    frames, _ = _frames(monkeypatch, {}, tf2_ros=False)
    assert not frames.uses_tf
    obs = Observations([10.0], [0.0])
    assert frames.observations("laser", T0, obs, SETTINGS, SensorConfig(offset_x=2.0)) is obs
    frames.check_odometry("base_link", SETTINGS)
    frames.check_odometry("base_footprint", SETTINGS)
    assert frames.diagnostics() == {"unexpected_child_frame.base_footprint": 1}


def _odom(ros, stamp, x, child):
    msg = Odometry(header=Header(stamp=conv.sec_to_stamp(stamp), frame_id="odom"), child_frame_id=child)
    msg.pose.pose.position.x = float(x)
    msg.pose.pose.orientation.w = 1.0
    ros.odom_pub.publish(msg)


def test_live_node_places_the_landmark_through_tf_and_checks_the_frames(ros, monkeypatch):
    """The node with (fake) tf2_ros: the laser's mount comes from TF, not from sensor.offset_*;
    odometry of another child frame and clouds in an unknown frame are counted."""
    monkeypatch.setitem(sys.modules, "tf2_ros", fake_tf2_ros({("base_link", "laser"): (1.0, 0.5, math.pi / 2)}))
    node = ros.start(motion_source="odom", sensor_frame="laser", publish_particles=False)
    assert node.inputs.frames.uses_tf and not node.outputs.transform.kind.startswith("tf2_ros")
    header = lambda t, frame: Header(stamp=conv.sec_to_stamp(t), frame_id=frame)  # noqa: E731
    for k in range(30):
        t = T0 + 0.05 * k
        _odom(ros, t, 0.0, "base_link" if k < 20 else "base_footprint")
        if k % 2 == 0:
            # Landmark 7 straight ahead of the laser, 2 m: (1, 2.5) in the base frame.
            ros.cloud_pub.publish(conv.observations_to_cloud(header(t, "laser"), [2.0], [0.0], [7]))
        if k == 10:
            ros.cloud_pub.publish(conv.observations_to_cloud(header(t + 0.01, "camera"), [], []))
        ros.spin_for(0.005)
    assert ros.spin_until(lambda: len(node.slam.landmarks()) == 1, 10.0)
    assert node.slam.landmarks().positions[0] == pytest.approx((1.0, 2.5), abs=0.3)

    def counted():
        d = ros.diagnostics()
        return (d.get("unexpected_child_frame.base_footprint") == "10" and d.get("unexpected_frame.camera") == "1"
                and int(d.get("sensor_pose_from_tf", 0)) == 15 and d.get("sensor_pose_tf_failures") == "1")
    assert ros.spin_until(counted, 10.0), ros.diagnostics()
    assert "unexpected_child_frame.base_link" not in ros.diagnostics()


def test_live_odometry_child_frame_checked_against_base_frame(ros):
    """Without tf2_ros: odometry whose child_frame_id is not base_frame is used, counted."""
    node = ros.start(motion_source="odom", base_frame="base_footprint")
    for k in range(6):
        _odom(ros, T0 + 0.1 * k, 0.1 * k, "base_link")
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 0.5), 5.0)      # still used
    assert ros.spin_until(lambda: ros.diagnostics().get("unexpected_child_frame.base_link") == "6", 5.0), \
        ros.diagnostics()
    assert not ros.drops()
