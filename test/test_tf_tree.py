"""The converted Car Park bag carries a complete TF tree (no rclpy needed)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from online_em_slam.bag.bagio import read_bag


@pytest.fixture(scope="module")
def car_park_bag(tmp_path_factory):
    from online_em_slam.datasets.kth.convert import convert
    bag = tmp_path_factory.mktemp("bags") / "car_park"
    convert("car_park", bag, progress=False)
    return bag


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _latched(bag, topic) -> bool:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability
    with AnyReader([bag]) as reader:
        (conn,) = [c for c in reader.connections if c.topic == topic]
        return any(p.durability == QosDurability.TRANSIENT_LOCAL for p in conn.ext.offered_qos_profiles)


def test_odom_to_base_link_on_tf_matches_odometry(car_park_bag):
    odom = [(s, m) for _, s, m in read_bag(car_park_bag, ["/odom"])]
    tf = [m for _, _, m in read_bag(car_park_bag, ["/tf"])]
    assert len(tf) == len(odom) == 5001
    for k in (0, 2500, 5000):
        (t,) = tf[k].transforms
        stamp, o = odom[k]
        assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
        assert t.header.stamp.sec + t.header.stamp.nanosec * 1e-9 == pytest.approx(stamp, abs=1e-9)
        p = o.pose.pose.position
        assert (t.transform.translation.x, t.transform.translation.y) == pytest.approx((p.x, p.y))
        assert _yaw(t.transform.rotation) == pytest.approx(_yaw(o.pose.pose.orientation))
    assert not _latched(car_park_bag, "/tf")


def test_static_base_link_to_laser_and_map_to_gps(car_park_bag):
    (msg,) = [m for _, _, m in read_bag(car_park_bag, ["/tf_static"])]
    by_child = {t.child_frame_id: t for t in msg.transforms}
    laser, gps = by_child["laser"], by_child["gps"]
    assert laser.header.frame_id == "base_link" and gps.header.frame_id == "map"
    assert (laser.transform.translation.x, laser.transform.translation.y) == (3.78, 0.5)
    assert _latched(car_park_bag, "/tf_static")
    # Overlay: GPS fixes brought into the map frame by map -> gps follow the dead-reckoned
    # laser point over the first 30 s (map = odom at the start for a node at (0, 0, 0)).
    yaw = _yaw(gps.transform.rotation)
    R = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    t = np.array([gps.transform.translation.x, gps.transform.translation.y])
    fixes = [(s, m.point) for _, s, m in read_bag(car_park_bag, ["/ground_truth/position"])]
    assert {m.header.frame_id for _, _, m in read_bag(car_park_bag, ["/ground_truth/landmarks"])} == {"gps"}
    odom = [(s, m.pose.pose) for _, s, m in read_bag(car_park_bag, ["/odom"])]
    ot = np.array([s for s, _ in odom])
    errors = []
    for stamp, point in fixes:
        if stamp > ot[0] + 30:
            break
        pose = odom[int(np.searchsorted(ot, stamp).clip(0, len(ot) - 1))][1]
        c, s = math.cos(_yaw(pose.orientation)), math.sin(_yaw(pose.orientation))
        laser_point = np.array([pose.position.x + 3.78 * c - 0.5 * s, pose.position.y + 3.78 * s + 0.5 * c])
        errors.append(np.linalg.norm(R @ np.array([point.x, point.y]) + t - laser_point))
    assert len(errors) > 50 and np.median(errors) < 1.0


def test_no_map_to_gps_option(tmp_path):
    from online_em_slam.datasets.convert import main
    out = tmp_path / "cp"
    assert main(["car_park", str(out), "--no-progress", "--no-map-to-gps"]) == 0
    (msg,) = [m for _, _, m in read_bag(out, ["/tf_static"])]
    assert [t.child_frame_id for t in msg.transforms] == ["laser"]
