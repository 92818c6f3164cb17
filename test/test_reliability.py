"""Issue 12 (reliability), pure-Python parts: parameters that used to crash the
node at the next reset (defect 3), map paths (defect 8), path publishing cost
(defect 9), odometry quaternions (defect 10) and the decoding of observation
clouds (ids, range types, zero ranges, huge bearings).  Live-node checks are in
test_reliability_node.py."""
import math

import numpy as np
import pytest

from online_em_slam.core.config import AssociationConfig, FilterConfig, ObservationNoiseConfig, SlamConfig
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.parameters.specs import ParameterError, build


# ----------------------------------------------------------------- defect 3: parameters
@pytest.mark.parametrize("std", [(1.0, 1.0), (1.0,), (1.0, 1.0, 1.0, 1.0), ()])
def test_initial_pose_std_needs_exactly_three_entries(std):
    with pytest.raises(ValueError, match=r"filter\.initial_pose_std .*exactly 3"):
        FilterConfig(initial_pose_std=std).validate()


def test_initial_pose_std_scalar_is_refused_not_broadcast():
    with pytest.raises(ValueError, match=r"filter\.initial_pose_std"):
        FilterConfig(initial_pose_std=1.0).validate()


@pytest.mark.parametrize("field, value", [
    ("mixture_weights", (math.nan, 1.0)), ("mixture_weights", (0.5, math.nan)),
    ("mixture_weights", (math.inf, 0.0)), ("mixture_scales", (1.0, math.nan)),
    ("mixture_scales", (math.inf, 5.0)), ("mixture_scales", (1.0, -5.0))])
def test_non_finite_mixture_entries_are_refused(field, value):
    with pytest.raises(ValueError, match=rf"noise\.{field}"):
        ObservationNoiseConfig(model="mixture", **{field: value}).validate()


def test_gate_probability_one_names_gate_probability():
    with pytest.raises(ValueError, match=r"association\.gate_probability = 1\.0") as error:
        AssociationConfig(gate_probability=1.0).validate()
    assert "new_landmark_probability" not in str(error.value)
    with pytest.raises(ValueError, match=r"association\.new_landmark_probability = 1\.0"):
        AssociationConfig(new_landmark_probability=1.0).validate()


@pytest.mark.parametrize("name, value", [
    ("filter.initial_pose_std", [1.0, 1.0]), ("filter.initial_pose_std", [1.0]),
    ("noise.mixture_weights", [math.nan, 1.0]), ("noise.mixture_scales", [1.0, math.inf]),
    ("association.gate_probability", 1.0)])
def test_node_parameter_build_refuses_with_the_parameter_name(name, value):
    """What the node's on-set-parameters callback runs: a refusal naming the parameter,
    never a value that is accepted and crashes the next reset."""
    with pytest.raises(ParameterError, match=name.replace(".", r"\.")):
        build({name: value})


def _hostile_values(default):
    if isinstance(default, list):
        n = len(default)
        return [[], [1.0], [1.0, 1.0], [math.nan] * n, [math.inf] * n, [-1.0] * n, [0.0] * n, [1e300] * n,
                default + [0.0]]
    if isinstance(default, int):
        return [0, -1, 1, 2 ** 31 - 1, 2 ** 62]
    return [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e-300, 1e300]


def test_every_accepted_core_parameter_value_survives_a_reset_and_steps():
    """Fuzz every numeric core parameter with hostile values: each is refused by
    build() (what the node's set-parameters callback runs) or the estimator built
    from it resets and runs; none is accepted and then crashes (defect 3)."""
    from online_em_slam.core.types import Observations
    from online_em_slam.parameters.specs import core_specs
    tried = accepted = 0
    for spec in core_specs():
        if isinstance(spec.default, (bool, str)):
            continue
        for value in _hostile_values(spec.default):
            tried += 1
            values = {spec.name: value} if spec.name == "filter.num_particles" else {
                spec.name: value, "filter.num_particles": 5}
            try:
                config, _ = build(values)
            except ParameterError:
                continue
            if config.filter.num_particles > 1000:
                continue
            accepted += 1
            slam = OnlineEMSlam(config)
            slam.reset((0.0, 0.0, 0.0))
            for k in range(4):
                slam.add_odometry(0.1 * k, np.array([0.1 * k, 0.0, 0.0]))
                slam.add_observations(0.1 * k + 0.05, Observations([5.0, 7.0], [0.1, -0.3], [1, -1]))
            assert np.all(np.isfinite(slam.pose().mean)), (spec.name, value)
    assert tried > 200 and 0 < accepted < tried


def test_every_accepted_initial_pose_std_survives_a_reset():
    config, _ = build({"filter.initial_pose_std": [0.5, 0.5, 0.1], "filter.num_particles": 10})
    slam = OnlineEMSlam(config)
    slam.reset(initial_pose=(1.0, 2.0, 0.3))
    assert np.all(np.isfinite(slam.particles()[0]))
    SlamConfig().validate()


# ----------------------------------------------------------------- observation clouds
def make_cloud(columns: dict, layout):
    """A sensor_msgs/PointCloud2 of ``columns`` laid out as ``layout``."""
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    from online_em_slam.messages.cloud import build_message
    return build_message(PointCloud2, PointField, Header(), columns, layout)


def test_uint8_range_field_is_refused_as_malformed():
    from online_em_slam.ros import conversions as conv
    cloud = make_cloud({"range": np.array([5, 6]), "bearing": np.array([0.0, 0.1])}, (("range", "u1"), ("bearing", "f4")))
    with pytest.raises(conv.CloudFormatError, match="'range' has integer type uint8"):
        conv.observations_from_cloud(cloud)


@pytest.mark.parametrize("id_type, good_ids, bad_ids", [
    ("f4", [3, -1, 2 ** 24], [np.nan, 1e20, 2.5, -7.0, 2 ** 31 - 1]),   # float32(2^31 - 1) is 2^31
    ("f8", [3, -1, 2 ** 31 - 1], [np.inf, 2.0 ** 31, 3e9, -2.0]),
    ("u4", [3, 7], [2 ** 31, 2 ** 32 - 1]), ("i2", [3, -1], [-5])])
def test_invalid_ids_are_dropped_and_counted_not_treated_as_unknown(id_type, good_ids, bad_ids):
    from collections import Counter
    from online_em_slam.ros import conversions as conv
    ids = np.array(good_ids + bad_ids, dtype=float)
    n = len(ids)
    cloud = make_cloud({"range": np.full(n, 5.0), "bearing": np.zeros(n), "id": ids},
                       (("range", "f4"), ("bearing", "f4"), ("id", id_type)))
    drops = Counter()
    obs = conv.observations_from_cloud(cloud, drops=drops)
    assert obs.ids.tolist() == good_ids
    assert drops == {"invalid_id": len(bad_ids)}



@pytest.mark.parametrize("columns, layout, reason", [
    ({"range": np.full(3, 5.0), "bearing": np.zeros(3), "id": np.array([np.nan, 1e20, -7.0])},
     (("range", "f4"), ("bearing", "f4"), ("id", "f8")), "invalid_id"),
    ({"range": np.zeros(2), "bearing": np.zeros(2)}, (("range", "f4"), ("bearing", "f4")), "zero_range")])
def test_a_cloud_emptied_by_refused_points_is_counted_once_under_their_reason(columns, layout, reason):
    """Issue 12: a cloud whose ids are all invalid was counted as invalid_id and again as empty_cloud."""
    from collections import Counter
    from online_em_slam.pipeline import OBSERVATIONS, ODOMETRY, Feeder, Input
    from online_em_slam.ros import conversions as conv
    drops = Counter()
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    feeder = Feeder(OnlineEMSlam(config), "odom", drops)
    feeder.apply(Input(0.0, ODOMETRY, payload=(0.0, 0.0, 0.0)))
    emptied = conv.observations_from_cloud(make_cloud(columns, layout), drops=drops)
    fed = feeder.apply(Input(0.1, OBSERVATIONS, payload=emptied))
    truly_empty = conv.observations_from_cloud(make_cloud({"range": np.zeros(0), "bearing": np.zeros(0)},
                                                          (("range", "f4"), ("bearing", "f4"))), drops=drops)
    feeder.apply(Input(0.2, OBSERVATIONS, payload=truly_empty))
    assert fed.trajectory_point is not None          # still "nothing seen up to here" for the path
    assert drops == {reason: len(columns["range"]), "empty_cloud": 1}, drops

def test_zero_ranges_and_huge_bearings_are_dropped_and_counted_bearings_wrapped():
    from collections import Counter
    from std_msgs.msg import Header
    from online_em_slam.ros import conversions as conv
    ranges = [0.0, 5.0, 5.0, 5.0, 5.0, -1.0, np.nan]
    bearings = [0.1, 1e20, -50.0, 1.5 * np.pi, -0.2, 0.0, 0.0]
    drops = Counter()
    obs = conv.observations_from_cloud(conv.observations_to_cloud(Header(), ranges, bearings), drops=drops)
    assert drops == {"zero_range": 1, "bearing_out_of_range": 2}
    # Negative and non-finite ranges go on to the core, which drops and counts them.
    assert obs.ranges.tolist()[:2] == [5.0, 5.0] and len(obs) == 4
    np.testing.assert_allclose(obs.bearings[:2], [-0.5 * np.pi, -0.2], atol=1e-6)


def test_landmark_ids_beyond_int32_are_not_published_wrapped():
    from std_msgs.msg import Header
    from online_em_slam.messages.cloud import decode_message
    from online_em_slam.core.types import LandmarkMap
    from online_em_slam.ros import conversions as conv
    ids = np.array([5, 2 ** 31 + 5, 2 ** 31 - 1, 2 ** 32 + 5])
    landmarks = LandmarkMap(ids, np.arange(8.0).reshape(4, 2), np.tile(np.eye(2), (4, 1, 1)),
                            np.ones(4, dtype=int), np.ones(4, dtype=bool))
    cloud, skipped = conv.landmarks_to_cloud(Header(frame_id="map"), landmarks)
    assert decode_message(cloud)["id"].tolist() == [5, 2 ** 31 - 1]
    assert skipped == {"landmark_id_out_of_range": 2}
    markers = conv.landmarks_to_markers(Header(frame_id="map"), landmarks).markers[1:]
    marker_ids = sorted({m.id for m in markers})
    assert marker_ids == [5, 2 ** 31 - 1] and all(m.id >= 0 for m in markers)


# ----------------------------------------------------------------- defect 10: odometry quaternions
def test_odometry_quaternions_normalised_degenerate_ones_rejected():
    from geometry_msgs.msg import Quaternion
    from online_em_slam.ros import conversions as conv
    q = conv.yaw_to_quaternion(1.2)
    assert conv.odometry_yaw(q) == (pytest.approx(1.2), None)
    scaled = Quaternion(x=3 * q.x, y=3 * q.y, z=3 * q.z, w=3 * q.w)
    assert conv.odometry_yaw(scaled) == (pytest.approx(1.2), "unnormalised_quaternion")
    huge = Quaternion(x=0.0, y=0.0, z=1e300 * q.z, w=1e300 * q.w)
    assert conv.odometry_yaw(huge) == (pytest.approx(1.2), "unnormalised_quaternion")
    tiny = Quaternion(x=0.0, y=0.0, z=1e-3 * q.z, w=1e-3 * q.w)
    assert conv.odometry_yaw(tiny) == (pytest.approx(1.2), "unnormalised_quaternion")
    for degenerate in (Quaternion(x=0.0, y=0.0, z=0.0, w=0.0), Quaternion(x=0.0, y=0.0, z=1e-12, w=0.0),
                       Quaternion(x=0.0, y=math.sqrt(0.5), z=0.0, w=math.sqrt(0.5))):     # pitch 90 deg
        yaw, problem = conv.odometry_yaw(degenerate)
        assert math.isnan(yaw) and problem == "degenerate_quaternion"
    yaw, problem = conv.odometry_yaw(Quaternion(x=0.0, y=0.0, z=math.nan, w=1.0))
    assert math.isnan(yaw) and problem is None                 # the node's non-finite check


# ----------------------------------------------------------------- defect 9: path publishing cost
def test_path_history_is_bounded_stable_and_keeps_the_newest_pose():
    from std_msgs.msg import Header
    from online_em_slam.ros.path_history import PathHistory
    path = PathHistory(maxlen=10_000, max_poses=100)
    for k in range(25_000):
        path.append(1000.0 + 0.1 * k, (k, 0.0, 0.0))
    assert len(path) == 10_000 and path._rows.nbytes <= 10_000 * 32
    msg = path.to_msg(Header(frame_id="map"))
    assert 50 <= len(msg.poses) <= 100
    xs = [p.pose.position.x for p in msg.poses]
    assert xs[-1] == 24_999 and xs[0] >= 15_000 and xs == sorted(xs)
    # Incremental: the next publish reuses the PoseStamped objects it built.
    path.append(1000.0 + 0.1 * 25_000, (25_000, 0.0, 0.0))
    again = path.to_msg(Header(frame_id="map"))
    reused = {id(p) for p in msg.poses} & {id(p) for p in again.poses}
    assert len(reused) >= len(again.poses) - 2
    assert not path.append(1000.0 + 0.1 * 25_000, (1.0, 0.0, 0.0))          # repeated stamp
    assert not path.append(5000.0, (math.nan, 0.0, 0.0))
    path.resize(10)
    assert len(path) == 10 and path.to_msg(Header()).poses[-1].pose.position.x == 25_000
    path.resize(0)
    assert not path.append(6000.0, (0.0, 0.0, 0.0)) and len(path.to_msg(Header()).poses) == 0


def test_path_max_length_range_is_what_the_node_can_serve():
    with pytest.raises(ParameterError, match="path_max_length"):
        build({"path_max_length": 10_000_000})
    with pytest.raises(ParameterError, match="path_publish_max_poses"):
        build({"path_publish_max_poses": 1_000_000})


# ----------------------------------------------------------------- defect 8: map paths
def test_map_file_is_read_only_and_confined_in_the_parameter_table():
    from online_em_slam.parameters.specs import NODE_SPECS
    specs = {spec.name: spec for spec in NODE_SPECS}
    assert specs["map_file"].read_only and specs["map_directory"].read_only


def test_a_time_line_restart_keeps_the_map_and_takes_earlier_stamps():
    """Issue 12 defect 6: the automatic reset on a confirmed time jump keeps the map."""
    from online_em_slam.core.types import Observations
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 20}})
    slam = OnlineEMSlam(config)
    for k in range(5):
        slam.add_odometry(100.0 + 0.1 * k, (0.1 * k, 0.0, 0.0))
        slam.add_observations(100.0 + 0.1 * k, Observations(np.array([5.0 - 0.1 * k]), np.zeros(1), np.array([7])))
    before = slam.landmarks()
    slam.restart_time_line((0.0, 0.0, 0.0))
    assert slam.last_stamp is None
    np.testing.assert_array_equal(slam.landmarks().positions, before.positions)
    assert slam.add_odometry(10.0, (50.0, 50.0, 1.0))          # a new odometry frame: a reference, no motion
    assert slam.add_odometry(10.1, (50.1, 50.0, 1.0))
    slam.add_observations(10.1, Observations(np.array([4.9]), np.zeros(1), np.array([7])))
    after = slam.landmarks()
    assert len(after) == 1 and after.n_obs[0] == before.n_obs[0] + 1 and "out_of_order" not in slam.drops


def test_throttled_log_calls_the_logger_once_per_period_and_key():
    """A warning repeated per input costs a dictionary lookup while throttled (ros/throttle.py)."""
    from online_em_slam.ros.throttle import Throttle
    now, said = [0.0], []

    class Logger:
        def warning(self, message):
            said.append(message)
    throttle = Throttle(Logger, lambda: 5.0, clock=lambda: now[0])
    for t in (0.0, 1.0, 4.9, 5.0, 6.0):
        now[0] = t
        throttle.warning("a", f"a at {t}")
        throttle.warning("b", f"b at {t}", period=1.0)
    assert said == ["a at 0.0", "b at 0.0", "b at 1.0", "b at 4.9", "a at 5.0", "b at 6.0"]
