"""The one PointCloud2 builder/decoder and the one yaw helper, with rclpy and rosbags messages alike."""
import math
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from online_em_slam.messages.cloud import OBSERVATION_FIELDS, build_message, decode_message, observations_from_message
from online_em_slam.messages.quaternion import odometry_yaw, quaternion_to_yaw, yaw_to_xyzw


def _rosbags_types():
    from rosbags.typesys import Stores, get_typestore
    types = get_typestore(Stores.ROS2_JAZZY).types
    return types["sensor_msgs/msg/PointCloud2"], types["sensor_msgs/msg/PointField"], types["std_msgs/msg/Header"]


def _rclpy_types():
    from sensor_msgs.msg import PointCloud2, PointField
    return PointCloud2, PointField


def _rosbags_header(header_type):
    from rosbags.typesys import Stores, get_typestore
    time_type = get_typestore(Stores.ROS2_JAZZY).types["builtin_interfaces/msg/Time"]
    return header_type(stamp=time_type(sec=1, nanosec=0), frame_id="laser")


@pytest.mark.parametrize("library", ["rclpy", "rosbags"])
def test_builder_and_decoder_round_trip(library):
    columns = {"x": np.array([1.0, 2.0]), "y": np.zeros(2), "z": np.zeros(2), "range": np.array([5.0, 6.0]),
               "bearing": np.array([0.1, -0.2]), "id": np.array([3, -1]), "range_std": np.full(2, np.nan),
               "bearing_std": np.full(2, np.nan)}
    if library == "rclpy":
        from std_msgs.msg import Header
        cloud_type, field_type = _rclpy_types()
        msg = build_message(cloud_type, field_type, Header(frame_id="laser"), columns, OBSERVATION_FIELDS)
    else:
        cloud_type, field_type, header_type = _rosbags_types()
        msg = build_message(cloud_type, field_type, _rosbags_header(header_type), columns, OBSERVATION_FIELDS,
                            raw_data=True)
    assert msg.width == 2 and msg.point_step == 32
    decoded = decode_message(msg)
    assert np.allclose(decoded["range"], [5.0, 6.0]) and list(decoded["id"]) == [3, -1]
    obs = observations_from_message(msg)
    assert list(obs.ids) == [3, -1] and np.allclose(obs.bearings, [0.1, -0.2])


def test_observation_reader_counts_what_it_refuses():
    from std_msgs.msg import Header
    cloud_type, field_type = _rclpy_types()
    columns = {"range": np.array([5.0, 0.0, 5.0, 5.0]), "bearing": np.array([0.0, 0.0, 10.0, 0.0]),
               "id": np.array([1.0, 2.0, 3.0, 2.5])}
    msg = build_message(cloud_type, field_type, Header(), columns, (("range", "f4"), ("bearing", "f4"), ("id", "f8")))
    drops = Counter()
    obs = observations_from_message(msg, drops)
    assert list(obs.ids) == [1]
    assert drops == Counter(zero_range=1, bearing_out_of_range=1, invalid_id=1)


def test_yaw_helper_on_plain_attribute_objects():
    for yaw in (-3.0, -0.5, 0.0, 1.2, math.pi):
        x, y, z, w = yaw_to_xyzw(yaw)
        q = SimpleNamespace(x=x, y=y, z=z, w=w)
        assert quaternion_to_yaw(q) == pytest.approx(math.remainder(yaw, 2 * math.pi), abs=1e-12)
        assert odometry_yaw(q)[1] is None
    assert odometry_yaw(SimpleNamespace(x=0.0, y=0.0, z=0.0, w=0.0)) == (pytest.approx(math.nan, nan_ok=True),
                                                                         "degenerate_quaternion")


def test_runner_reads_observations_with_the_node_checks():
    """The offline runner counts refused observations (runner_skipped) as the node counts them."""
    from std_msgs.msg import Header

    from online_em_slam.offline.runner import BagReader
    settings = SimpleNamespace(motion_source="control", observations_topic="obs", odom_topic="odom",
                               control_topic="control")
    reader = BagReader(settings)
    cloud_type, field_type = _rclpy_types()
    good = build_message(cloud_type, field_type, Header(), {"range": np.array([5.0, 5.0]),
                                                            "bearing": np.zeros(2), "id": np.array([1, -7])},
                         (("range", "f4"), ("bearing", "f4"), ("id", "i4")))
    bad = build_message(cloud_type, field_type, Header(), {"range": np.array([5], dtype=np.uint8)},
                        (("range", "u1"),))
    reader.observations(1.0, good)
    reader.observations(2.0, bad)
    assert len(reader.events) == 1 and list(reader.events[0][2].ids) == [1]
    assert reader.refused == Counter(invalid_id=1, malformed_cloud=1)
