"""KTH dataset loaders, beacon extraction and bag conversion (no rclpy needed)."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from online_em_slam.messages.cloud import OBSERVATION_FIELDS, decode_message
from online_em_slam.datasets.kth import datasets
from online_em_slam.datasets.kth.beacons import extract_beacons, observation_columns
from online_em_slam.datasets.kth.datasets import (VEHICLE, default_data_dir, load_car_park, load_tree_detections,
                                                  load_victoria_park)

INC = math.radians(0.5)


@pytest.fixture(scope="module")
def car_park():
    return load_car_park()


@pytest.fixture(scope="module")
def victoria_park():
    return load_victoria_park()


# --------------------------------------------------------------------------- loaders

def test_default_data_dir_finds_the_project_copy():
    d = default_data_dir()
    assert (d / "car_park" / "data_set.mat").is_file()
    assert (d / "victoria_park" / "tree_detections.dat").is_file()


def test_data_dir_from_environment(monkeypatch, tmp_path):
    (tmp_path / "kth" / "car_park").mkdir(parents=True)
    monkeypatch.setenv(datasets.DATA_ENV_VAR, str(tmp_path))
    assert default_data_dir() == tmp_path / "kth"


def test_car_park_sizes(car_park):
    cp = car_park
    assert len(cp.odometry) == 5001 and cp.odometry.speed.shape == cp.odometry.steering.shape == (5001,)
    assert cp.scans.ranges.shape == cp.scans.intensities.shape == (586, 361)
    assert len(cp.scans) == 586
    assert len(cp.gps) == 626 and cp.gps.xy.shape == (626, 2)
    assert cp.beacons.shape == (15, 2)
    assert 45.0 <= cp.odometry.times[0] < 45.1 and 170.0 < cp.odometry.times[-1] <= 170.2
    assert np.all(np.diff(cp.odometry.times) > 0) and np.all(np.diff(cp.scans.times) > 0)
    # beam k at k/2 deg - 90 deg in the sensor frame: beam 180 is straight ahead
    angles = cp.scans.beam_angles
    assert angles[0] == pytest.approx(-math.pi / 2) and angles[180] == pytest.approx(0.0, abs=1e-12)
    assert angles[-1] == pytest.approx(math.pi / 2)
    # merged event list: 0-based indices into the streams
    assert set(np.unique(cp.event_sensors)) == {1, 2, 3}
    laser = cp.event_sensors == 3
    np.testing.assert_allclose(cp.scans.times[cp.event_indices[laser]], cp.event_times[laser])


def test_victoria_park_sizes_and_time_offset(victoria_park):
    vp = victoria_park
    assert len(vp.dr) == 61945
    assert vp.dr.times[-1] - vp.dr.times[0] == pytest.approx(1548.6, abs=0.1)
    assert vp.dr.times[0] == pytest.approx(21.94)           # ms -> s
    assert len(vp.gps) == 4466 and vp.gps.times[0] == pytest.approx(20.967)
    trees = vp.trees
    assert len(trees) == 7230 and trees.n_detections == 52974
    assert trees.offsets[0] == 0 and trees.offsets[-1] == 52974 and np.all(np.diff(trees.offsets) > 0)
    # first row of the file: 0.852  20.46202  0.88575  0.35404
    first = trees.scan(0)
    assert first.time == pytest.approx(0.852 + 20.967)
    assert first.range[0] == pytest.approx(20.46202)
    assert first.bearing[0] == pytest.approx(0.88575 - math.pi / 2)
    assert first.diameter[0] == pytest.approx(0.35404)
    assert trees.centre_range[0] == pytest.approx(20.46202 + 0.35404 / 2)
    # detections fall inside the dead-reckoning time span, bearings in the forward half plane
    assert vp.dr.times[0] - 1 < trees.times[0] and trees.times[-1] < vp.dr.times[-1] + 1
    assert np.all(np.abs(trees.bearing) <= math.pi / 2)


def test_tree_detection_parser_groups_rows(tmp_path):
    path = tmp_path / "trees.dat"
    path.write_text("1.000 10.0 1.5707963 0.2\n1.000 5.0 0.0 0.4\n2.500 7.0 3.1415926 0.1\n")
    trees = load_tree_detections(path, time_offset=10.0)
    assert list(trees.times) == [11.0, 12.5]
    assert list(trees.offsets) == [0, 2, 3]
    np.testing.assert_allclose(trees.bearing, [0.0, -math.pi / 2, math.pi / 2], atol=1e-6)
    assert [len(s.range) for s in trees] == [2, 1]


def test_missing_data_dir_raises(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_car_park(tmp_path)


# --------------------------------------------------------------------------- beacons

def _scan(n=361, fill=81.9):
    return np.full(n, fill), np.zeros(n)


def test_extract_beacons_hand_made_scan():
    r, inten = _scan()
    r[100:103] = [10.0, 10.2, 10.4]; inten[100:103] = 8192        # 3-beam cluster centred on beam 101
    r[180] = 5.0; inten[180] = 16384                                # single beam straight ahead
    r[300:302] = [20.0, 20.0]; inten[300:302] = [8192, 32768]      # centre between beams 300 and 301
    r[50] = 3.0                                                     # no intensity: ignored
    inten[60] = 8192                                                # intensity but no return: ignored
    b = extract_beacons(r, inten, -math.pi / 2, INC)
    assert len(b) == 3
    np.testing.assert_allclose(b.range, [10.2, 5.0, 20.0])
    np.testing.assert_allclose(b.bearing, [math.radians(101 / 2 - 90), 0.0, math.radians(300.5 / 2 - 90)],
                               atol=1e-12)
    assert list(b.n_beams) == [3, 1, 2]


def test_extract_beacons_radius_threshold_and_splitting():
    r, inten = _scan(20)
    r[5:9] = [8.0, 8.0, 12.0, 12.0]; inten[5:9] = 1
    b = extract_beacons(r, inten, 0.0, 0.1)
    np.testing.assert_allclose(b.range, [8.0, 12.0])                    # split at the range jump
    np.testing.assert_allclose(b.bearing, [0.55, 0.75])
    assert len(extract_beacons(r, inten, 0.0, 0.1, max_range_jump=None)) == 1
    np.testing.assert_allclose(extract_beacons(r, inten, 0.0, 0.1, beacon_radius=0.1).range, [8.1, 12.1])
    assert len(extract_beacons(r, inten, 0.0, 0.1, min_intensity=2)) == 0
    assert len(extract_beacons(r, inten, 0.0, 0.1, max_range=10.0)) == 1
    r[0], inten[0] = np.inf, 1
    r[1], inten[1] = np.nan, 1
    assert len(extract_beacons(r, inten, 0.0, 0.1)) == 2
    with pytest.raises(ValueError):
        extract_beacons(r, inten[:-1], 0.0, 0.1)
    empty = extract_beacons(np.zeros(0), np.zeros(0), 0.0, 0.1)
    assert len(empty) == 0 and empty.range.shape == (0,)


def test_observation_columns_sensor_frame():
    cols = observation_columns([2.0, 3.0], [0.0, math.pi / 2])
    np.testing.assert_allclose(cols["x"], [2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(cols["y"], [0.0, 3.0])
    assert list(cols["id"]) == [-1, -1] and list(cols["range_std"]) == [0.0, 0.0]
    assert set(cols) == {name for name, _ in OBSERVATION_FIELDS}


def test_car_park_beacon_counts(car_park):
    sc = car_park.scans
    dets = [extract_beacons(r, i, sc.angle_min, sc.angle_increment) for r, i in zip(sc.ranges, sc.intensities)]
    total = sum(len(d) for d in dets)
    with_beacon = sum(len(d) > 0 for d in dets)
    assert 940 <= total <= 980          # README: about 960
    assert 495 <= with_beacon <= 515    # README: ~505 of 586
    assert total == 964 and with_beacon == 506   # measured; pins the extraction


def test_car_park_detections_match_surveyed_beacons(car_park):
    """Range from the GPS point (= laser) to the nearest-in-range surveyed beacon."""
    cp, sc = car_park, car_park.scans
    residuals = []
    for t, r, i in zip(sc.times, sc.ranges, sc.intensities):
        d = extract_beacons(r, i, sc.angle_min, sc.angle_increment)
        px, py = np.interp(t, cp.gps.times, cp.gps.x), np.interp(t, cp.gps.times, cp.gps.y)
        dist = np.hypot(cp.beacons[:, 0] - px, cp.beacons[:, 1] - py)
        for rr in d.range:
            residuals.append(rr - dist[np.argmin(np.abs(dist - rr))])
    residuals = np.asarray(residuals)
    assert np.mean(np.abs(residuals) < 0.5) > 0.99
    assert abs(np.median(residuals)) < 0.03


# --------------------------------------------------------------------------- streams and bags

def test_dead_reckoning_matches_acfr_model():
    from online_em_slam.datasets.kth.convert import acfr_rates, dead_reckon
    from online_em_slam.datasets.kth.datasets import OdometryStream
    t = np.arange(0, 10.0001, 0.025)
    ctrl = OdometryStream(t, np.full(t.size, 2.0), np.full(t.size, 0.1))
    dr = dead_reckon(ctrl)
    v_c, w = acfr_rates(2.0, 0.1)
    assert v_c == pytest.approx(2.0 / (1 - math.tan(0.1) * 0.76 / 2.83))
    assert w == pytest.approx(v_c * math.tan(0.1) / 2.83)
    assert dr.poses[-1, 2] == pytest.approx(math.remainder(w * 10.0, 2 * math.pi), abs=1e-9)
    # constant curvature: on a circle of radius v_c / w through the origin, tangent to x
    radius = v_c / w
    centre = np.array([0.0, radius])
    d = np.hypot(*(dr.poses[:, :2] - centre).T)
    assert np.max(np.abs(d - radius)) < 0.05
    straight = dead_reckon(OdometryStream(t, np.ones(t.size), np.zeros(t.size)))
    assert straight.poses[-1, 0] == pytest.approx(10.0) and straight.poses[-1, 1] == 0.0


def test_streams_car_park(car_park):
    from online_em_slam.datasets.kth.convert import car_park_streams, message_schedule
    s = car_park_streams(car_park)
    assert len(s.observations) == 586 and s.observations.n_detections == 964
    counts = s.message_counts()
    assert counts == {"/tf_static": 1, "/odom": 5001, "/tf": 5001, "/control": 5001, "/landmark_observations": 586,
                      "/ground_truth/position": 626, "/scan": 586, "/ground_truth/landmarks": 1}
    stamps, topics, _ = message_schedule(s)
    assert np.all(np.diff(stamps) >= 0)
    assert topics[:2] == ["/tf_static", "/ground_truth/landmarks"]
    assert Counter(topics) == counts
    # dead reckoning shape: the laser point track follows GPS closely at the start
    v = VEHICLE
    x, y, phi = s.odom.poses.T
    assert np.all(np.isfinite(s.odom.poses))
    laser = np.column_stack([x + v.sensor_x * np.cos(phi) - v.sensor_y * np.sin(phi),
                             y + v.sensor_x * np.sin(phi) + v.sensor_y * np.cos(phi)])
    path_dr = np.sum(np.hypot(*np.diff(laser[s.odom.times < 60], axis=0).T))
    g = s.gps.times < 60
    path_gps = np.sum(np.hypot(np.diff(s.gps.x[g]), np.diff(s.gps.y[g])))
    assert path_dr == pytest.approx(path_gps, rel=0.05)


def test_streams_victoria_park(victoria_park):
    from online_em_slam.datasets.kth.convert import victoria_park_streams
    s = victoria_park_streams(victoria_park)
    assert s.scans is None and s.landmarks is None
    assert s.message_counts() == {"/tf_static": 1, "/odom": 61945, "/tf": 61945, "/control": 61945,
                                  "/landmark_observations": 7230, "/ground_truth/position": 4466}
    np.testing.assert_allclose(s.observations.range, victoria_park.trees.range + victoria_park.trees.diameter / 2)
    assert s.start_time == pytest.approx(20.967)


@pytest.fixture(scope="module")
def car_park_bag(tmp_path_factory, car_park):
    from online_em_slam.datasets.kth.convert import car_park_streams, write_bag
    out = tmp_path_factory.mktemp("bags") / "car_park"
    counts = write_bag(car_park_streams(car_park), out, progress=False)
    return out, counts


def test_bag_round_trip_counts(car_park_bag):
    from online_em_slam.bag.bagio import bag_topics, count_messages
    path, counts = car_park_bag
    assert (path / "metadata.yaml").is_file() and list(path.glob("*.mcap"))
    expected = {"/tf_static": 1, "/odom": 5001, "/tf": 5001, "/control": 5001, "/landmark_observations": 586,
                "/ground_truth/position": 626, "/scan": 586, "/ground_truth/landmarks": 1}
    assert counts == expected
    assert {t: n for t, (_, n) in bag_topics(path).items()} == expected
    assert dict(count_messages(path)) == expected
    assert bag_topics(path)["/tf_static"][0] == "tf2_msgs/msg/TFMessage"


def test_bag_round_trip_values(car_park_bag, car_park):
    from online_em_slam.bag.bagio import read_bag
    path, _ = car_park_bag
    cp = car_park
    seen = Counter()
    log_order = []
    for topic, stamp, msg in read_bag(path):
        log_order.append(stamp)
        k = seen[topic]
        seen[topic] += 1
        if topic == "/control" and k in (0, 1234, 5000):
            assert stamp == pytest.approx(cp.odometry.times[k], abs=1e-9)
            assert msg.twist.linear.x == pytest.approx(cp.odometry.speed[k])
            assert msg.twist.angular.z == pytest.approx(cp.odometry.steering[k])
            assert msg.header.frame_id == "base_link"
        elif topic == "/odom" and k == 0:
            assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"
            assert msg.pose.pose.position.x == 0.0 and msg.pose.pose.orientation.w == 1.0
        elif topic == "/scan" and k in (0, 300):
            assert stamp == pytest.approx(cp.scans.times[k], abs=1e-9)
            assert msg.header.frame_id == "laser"
            assert msg.angle_min == pytest.approx(-math.pi / 2) and msg.angle_increment == pytest.approx(INC)
            valid = cp.scans.ranges[k] < 81.9
            np.testing.assert_allclose(msg.ranges[valid], cp.scans.ranges[k][valid], rtol=1e-6)
            assert np.all(np.isinf(msg.ranges[~valid]))
            np.testing.assert_array_equal(msg.intensities, cp.scans.intensities[k])
        elif topic == "/landmark_observations" and k in (0, 100):
            cols = decode_message(msg, required=[n for n, _ in OBSERVATION_FIELDS])
            sc = cp.scans
            ref = extract_beacons(sc.ranges[k], sc.intensities[k], sc.angle_min, sc.angle_increment)
            np.testing.assert_allclose(cols["range"], ref.range, rtol=1e-6)
            np.testing.assert_allclose(cols["bearing"], ref.bearing, atol=1e-6)
            np.testing.assert_allclose(cols["x"], ref.range * np.cos(ref.bearing), atol=1e-5)
            assert np.all(cols["id"] == -1) and msg.header.frame_id == "laser"
        elif topic == "/ground_truth/position" and k == 10:
            assert (msg.point.x, msg.point.y) == pytest.approx((cp.gps.x[10], cp.gps.y[10]))
            assert msg.header.frame_id == "gps"
        elif topic == "/ground_truth/landmarks":
            cols = decode_message(msg, required=["x", "y", "id"])
            np.testing.assert_allclose(np.column_stack([cols["x"], cols["y"]]), cp.beacons, atol=1e-5)
            assert list(cols["id"]) == list(range(15))
        elif topic == "/tf_static":
            tf = msg.transforms[0]           # then map -> gps (test_tools.py)
            assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
            assert (tf.transform.translation.x, tf.transform.translation.y) == (3.78, 0.5)
    assert np.all(np.diff(log_order) >= -1e-9)   # header stamps = log times here, in order
    assert sum(seen.values()) == 16803


def test_read_bag_topic_filter_and_sqlite(tmp_path, car_park):
    from online_em_slam.bag.bagio import read_bag
    from online_em_slam.datasets.kth.convert import car_park_streams, write_bag
    out = tmp_path / "cp_sqlite"
    write_bag(car_park_streams(car_park), out, storage="sqlite3", progress=False)
    assert list(out.glob("*.db3"))
    got = [(t, s) for t, s, _ in read_bag(out, ["/ground_truth/position"])]
    assert len(got) == 626 and {t for t, _ in got} == {"/ground_truth/position"}
    np.testing.assert_allclose([s for _, s in got], car_park.gps.times, atol=1e-9)
    assert list(read_bag(out, ["/nonexistent"])) == []
    with pytest.raises(FileExistsError):
        write_bag(car_park_streams(car_park), out, progress=False)


def test_convert_main_cli(tmp_path, capsys):
    from online_em_slam.datasets.convert import main
    out = tmp_path / "cp"
    assert main(["car_park", str(out), "--no-progress"]) == 0
    assert "16803 messages" in capsys.readouterr().out
    assert main(["car_park", str(out), "--no-progress"]) == 1          # exists
    assert main(["car_park", str(out), "--no-progress", "--overwrite", "--storage", "sqlite3"]) == 0
    assert main(["car_park", str(tmp_path / "x"), "--data-dir", str(tmp_path / "nowhere")]) == 1
    with pytest.raises(SystemExit):
        main(["mars", str(tmp_path / "y")])
