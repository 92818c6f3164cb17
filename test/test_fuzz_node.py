"""Fuzz test (issue 12): every malformed input class of the issue sent to one live node.

Normal data first (a map of two landmarks), then the garbage, interleaved on the
same time line, then normal data again.  The node must stay alive and keep
publishing, every output must be finite, every refused input must be counted
under a named ``dropped.<reason>`` in /diagnostics, and the map built before the
garbage must still be there.  Real rclpy in one process (fresh Context,
ROS_AUTOMATIC_DISCOVERY_RANGE=OFF, see conftest.py); deterministic: the node
processes inputs on arrival (input_delay 0) in the order they were published.
"""
import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from geometry_msgs.msg import Quaternion, TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from online_em_slam.messages.cloud import decode_message  # noqa: E402
from online_em_slam.ros import conversions as conv  # noqa: E402
from test_node import T0, finite_pose, landmark_table  # noqa: E402
from test_reliability import make_cloud  # noqa: E402

DT = 0.1
SPEED = 1.0                                   # m/s along x
LANDMARKS = {1: (20.0, 0.0), 2: (22.0, 3.0)}  # id -> map position
CAP = 100                                     # association.max_observations_per_scan


def _stamp(seconds: float) -> TimeMsg:
    """Any stamp a publisher can write, including negative and 2^31 - 1 s."""
    sec = math.floor(seconds)
    return TimeMsg(sec=int(max(min(sec, 2 ** 31 - 1), -2 ** 31)), nanosec=int((seconds - sec) * 1e9) % 10 ** 9)


def odometry(stamp: float, x: float, q: Quaternion | None = None, y: float = 0.0) -> Odometry:
    msg = Odometry(header=Header(stamp=_stamp(stamp), frame_id="odom"), child_frame_id="base_link")
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    msg.pose.pose.orientation = q if q is not None else Quaternion(w=1.0)
    return msg


def control(stamp: float, speed: float, steer: float) -> TwistStamped:
    msg = TwistStamped(header=Header(stamp=_stamp(stamp), frame_id="base_link"))
    msg.twist.linear.x, msg.twist.angular.z = float(speed), float(steer)
    return msg


def scan(stamp: float, x: float):
    """Range, bearing, id of the landmarks seen from (x, 0, 0)."""
    ids = sorted(LANDMARKS)
    dx = np.array([LANDMARKS[i][0] - x for i in ids])
    dy = np.array([LANDMARKS[i][1] for i in ids])
    return np.hypot(dx, dy), np.arctan2(dy, dx), ids


def cloud(stamp: float, ranges, bearings, ids=None):
    return conv.observations_to_cloud(Header(stamp=_stamp(stamp), frame_id="sensor"), ranges, bearings, ids)


def drive(ros, node, k0: int, steps: int) -> int:
    """Normal data: odometry, control and a scan every DT, processed before returning."""
    for k in range(k0, k0 + steps):
        t, x = T0 + DT * k, SPEED * DT * k
        ros.odom_pub.publish(odometry(t, x))
        ros.control_pub.publish(control(t, SPEED, 0.0))
        ros.cloud_pub.publish(cloud(t, *scan(t, x)))
    last = T0 + DT * (k0 + steps - 1)
    assert ros.spin_until(lambda: node.slam.last_stamp is not None
                          and node.slam.last_stamp >= last - 1e-6, 10.0), node.all_drops()
    return k0 + steps


def with_stamp(msg, stamp: float):
    msg.header.stamp = _stamp(stamp)
    return msg


# ----------------------------------------------------------------- the malformed classes
def bad_motion(t: float, x: float) -> list:
    """(topic, message) pairs of hostile odometry and control, each on its own stamp after t."""
    q = conv.yaw_to_quaternion(0.0)
    odom = [odometry(0, math.nan), odometry(0, x, y=math.inf), odometry(0, 1e300),
            odometry(0, x, Quaternion(x=math.nan, w=1.0)),
            odometry(0, x, Quaternion(x=0.0, y=0.0, z=0.0, w=0.0)),                 # zero quaternion
            odometry(0, x, Quaternion(y=math.sqrt(0.5), w=math.sqrt(0.5))),         # pitch 90 deg: no yaw
            odometry(0, x, Quaternion(z=1e300 * q.z, w=1e300 * q.w))]               # scaled: corrected
    twist = [control(0, math.nan, 0.0), control(0, SPEED, math.inf), control(0, 1e300, 0.0),
             control(0, SPEED, 1e3)]
    return ([("odom", with_stamp(m, t + 1e-3 * (i + 1))) for i, m in enumerate(odom)]
            + [("control", with_stamp(m, t + 1e-3 * (i + 1))) for i, m in enumerate(twist)])


def bad_stamps(x: float) -> list:
    """Lone inputs stamped 0, negative, far in the future and 2^31 - 1 s, on every topic."""
    out = []
    for bad in (0.0, -5.0, T0 + 1e6, 2.0 ** 31 - 1):
        if bad != 0.0:                          # a zero control stamp means "unstamped": arrival time
            out.append(("control", control(bad, SPEED, 0.0)))
        out += [("odom", odometry(bad, x)), ("cloud", cloud(bad, [5.0], [0.0], [1]))]
    return out


def bad_clouds(t: float, x: float) -> list:
    """The real scan at t twice, then hostile clouds, each on its own stamp after t (t after the motion's)."""
    missing_range = make_cloud({"bearing": np.zeros(2)}, (("bearing", "f4"),))
    uint8_range = make_cloud({"range": np.array([5, 6]), "bearing": np.zeros(2)}, (("range", "u1"), ("bearing", "f4")))
    integer_bearing = make_cloud({"range": np.ones(2), "bearing": np.zeros(2)}, (("range", "f4"), ("bearing", "i4")))
    float_ids = make_cloud({"range": np.full(3, 5.0), "bearing": np.zeros(3), "id": np.array([np.nan, 1e20, -7.0])},
                           (("range", "f4"), ("bearing", "f4"), ("id", "f8")))
    r, b, ids = scan(t, x)
    absurd_std = make_cloud({"range": r, "bearing": b, "id": np.array(ids), "range_std": np.array([1e200, 1e-200]),
                             "bearing_std": np.array([1e-200, 1e200])},             # the cloud that used to stop
                            (("range", "f4"), ("bearing", "f4"), ("id", "i4"),      # the estimator for good
                             ("range_std", "f8"), ("bearing_std", "f8")))
    rng = np.random.default_rng(0)
    flood = cloud(0, rng.uniform(3.0, 30.0, 8000), rng.uniform(-3.0, -2.0, 8000))   # 8000 unknown ids, behind
    hostile = [missing_range, uint8_range, integer_bearing, float_ids,
               cloud(0, [0.0, math.nan, -1.0], [0.0, 0.0, 0.0], [1, 1, 1]),       # zero, NaN, negative range
               cloud(0, [5.0, 5.0], [1e20, math.inf], [1, -1]),                   # huge and infinite bearings
               cloud(0, [], [], []), absurd_std, flood]
    return ([("cloud", cloud(t, *scan(t, x))), ("cloud", cloud(t, *scan(t, x)))]  # a repeated stamp
            + [("cloud", with_stamp(m, t + 1e-3 * (i + 1))) for i, m in enumerate(hostile)])


# What the garbage above must be counted as (exactly: every refusal has a name).
COMMON_DROPS = {"non_finite_odometry": 3, "degenerate_quaternion": 2,
                  "stamp_outlier": 8, "repeated_stamp": 1, "malformed_cloud": 3, "invalid_id": 3, "zero_range": 1,
                  "bearing_out_of_range": 1, "invalid_observation": 3, "invalid_std": 2,
                  "empty_cloud": 1,                 # the empty cloud (the float-id one is counted as invalid_id only)
                  "too_many_observations": 8000 - CAP}
EXPECTED_DROPS = {
    "odom": dict(COMMON_DROPS, implausible_odometry=1),            # the control topic is not read
    "control": dict(COMMON_DROPS, non_finite_control=2, implausible_control=2, implausible_odometry=1,
                    stamp_outlier=8 + 3),
}


def publish(ros, items, done) -> None:
    """Publish one group and spin until ``done()``: the node sees the groups in this order
    (within a topic order is kept, across topics the executor would interleave them)."""
    pubs = {"odom": ros.odom_pub, "control": ros.control_pub, "cloud": ros.cloud_pub}
    for topic, msg in items:
        pubs[topic].publish(msg)
    assert ros.spin_until(done, 10.0), ros.node.all_drops()


def counted(node, **expected):
    return lambda: all(node.all_drops().get(k, 0) >= v for k, v in expected.items())


def finite_transform(msg) -> bool:
    t, r = msg.transform.translation, msg.transform.rotation
    return all(map(math.isfinite, (t.x, t.y, t.z, r.x, r.y, r.z, r.w)))


def finite_map(msg) -> bool:
    columns = decode_message(msg, required=("x", "y"))
    return all(np.all(np.isfinite(np.asarray(c, dtype=float))) for c in columns.values())


@pytest.mark.parametrize("motion_source", ["odom", "control"])
def test_fuzz_every_malformed_class_against_one_live_node(ros, motion_source):
    node = ros.start(motion_source=motion_source, publish_particles=False, **{
        "filter.num_particles": 20, "filter.seed": 1, "association.max_observations_per_scan": CAP})
    k = drive(ros, node, 0, 20)
    before = node.slam.landmarks()
    positions = dict(zip(before.ids.tolist(), before.positions.tolist()))
    assert sorted(positions) == [1, 2]

    t, x = T0 + DT * k, SPEED * DT * k
    motion = [("odom", odometry(t, x))] + bad_motion(t, x)
    publish(ros, motion, counted(node, degenerate_quaternion=2, **(
        {"implausible_odometry": 1} if motion_source == "odom"
        else {"implausible_control": 2, "implausible_odometry": 1})))
    stamps = bad_stamps(x)
    publish(ros, [m for m in stamps if m[0] != "cloud"], counted(node, stamp_outlier=3))
    publish(ros, [m for m in stamps if m[0] == "cloud"], counted(node, stamp_outlier=7))
    publish(ros, bad_clouds(t + 0.01, x), counted(node, stamp_outlier=8, too_many_observations=1))
    steps = node.slam.step_count
    k = drive(ros, node, k + 1, 20)
    assert ros.spin_until(lambda: node.slam.step_count - steps >= 20, 5.0)   # every later scan updates

    drops = node.all_drops()
    merged = drops.pop("merged_new_landmark", 0)        # association outcomes of the flood, not garbage
    limited = drops.pop("new_landmark_limit", 0)        # of its CAP points, at most 50 become landmarks
    assert drops == EXPECTED_DROPS[motion_source], drops
    assert merged + limited < CAP
    # /diagnostics names every one of them.
    assert ros.spin_until(lambda: {**ros.drops(), **ros.decided()} == node.all_drops(), 5.0), (
        ros.drops(), ros.decided(), node.all_drops())

    # Alive and still publishing: a pose at the last stamp, a map published after the garbage.
    last = node.slam.last_stamp
    assert ros.spin_until(lambda: all(any(conv.stamp_to_sec(m.header.stamp) == pytest.approx(last)
                                          for m in ros.received[topic]) for topic in ("pose", "landmarks")), 5.0)
    # Every output finite.
    assert ros.received["pose"] and all(map(finite_pose, ros.received["pose"]))
    # An odometry pose at x = 1e300 is refused by the node itself (never published as ~/pose).
    assert all(np.max(np.abs([m.pose.pose.position.x, m.pose.pose.position.y])) < 1e6
               for m in ros.received["pose"])
    assert all(map(finite_map, ros.received["landmarks"]))
    transforms = ros.received["map_to_odom"]
    assert transforms and all(map(finite_transform, transforms)) or node.outputs.transform.kind.startswith("tf2")
    # The map from before the garbage is intact, and the normal data after it still refine it.
    table = landmark_table(ros.received["landmarks"][-1])
    assert ros.spin_until(lambda: int(ros.diagnostics().get("resets", -1)) == 0, 3.0)
    for i, (lx, ly) in LANDMARKS.items():
        assert table[i] == pytest.approx((lx, ly), abs=0.5)
        assert table[i] == pytest.approx(positions[i], abs=0.2)
    assert abs(node.slam.pose().mean[0] - SPEED * DT * (k - 1)) < 0.5


def test_observation_clouds_in_unexpected_frames_are_counted(ros):
    """issue 12 item 12: frame ids checked against the configured frames (warned, counted, used)."""
    node = ros.start(motion_source="odom", sensor_frame="laser", publish_particles=False)
    for k, frame in enumerate(("laser", "base_link", "map", "camera", "map")):
        ros.odom_pub.publish(odometry(T0 + DT * k, SPEED * DT * k))
        msg = cloud(T0 + DT * k, *scan(T0, SPEED * DT * k))
        msg.header.frame_id = frame
        ros.cloud_pub.publish(msg)
    assert ros.spin_until(lambda: ros.diagnostics().get("unexpected_frame.map") == "2"
                          and ros.diagnostics().get("unexpected_frame.camera") == "1", 5.0), ros.diagnostics()
    assert not any(k.startswith("unexpected_frame.") and k[17:] in ("laser", "base_link") for k in ros.diagnostics())
    assert node.slam.landmarks().n_obs.sum() == 10


def test_frames_without_a_name_or_changing_are_counted(ros):
    """Reliability, second round, item 7: an empty cloud frame, an odometry header frame that is not
    odom_frame, and (sensor_frame unset) a cloud frame other than the first cloud's are counted."""
    ros.start(motion_source="odom", publish_particles=False)
    for k, (cloud_frame, odom_frame) in enumerate((("laser", "odom"), ("", "odom"), ("camera", ""),
                                                   ("laser", "world"), ("base_link", "odom"))):
        msg = odometry(T0 + DT * k, SPEED * DT * k)
        msg.header.frame_id = odom_frame
        ros.odom_pub.publish(msg)
        msg = cloud(T0 + DT * k, *scan(T0, SPEED * DT * k))
        msg.header.frame_id = cloud_frame
        ros.cloud_pub.publish(msg)
    expected = {"unexpected_frame.(empty)": "1", "unexpected_frame.camera": "1",
                "unexpected_odom_frame.(empty)": "1", "unexpected_odom_frame.world": "1"}
    assert ros.spin_until(lambda: all(ros.diagnostics().get(k) == v for k, v in expected.items()), 5.0), \
        ros.diagnostics()
    assert "unexpected_frame.laser" not in ros.diagnostics() and "unexpected_frame.base_link" not in ros.diagnostics()
