"""Map files in fleet mode: FleetSlam.load_map (core/fleet/slam.py) and the node's
map services on a fleet (FleetEstimate.load_map, ros/map_files.py)."""
import copy

import numpy as np
import pytest

from online_em_slam.core import AssociationConfig, FleetSlam, OnlineEMSlam
from online_em_slam.core.fleet.robot import FleetRobot
from online_em_slam.core.mapping.mapfile import MapFileError
from online_em_slam.core.mapping.persistence import saved_pose
from online_em_slam.experiments.simulation import ScenarioConfig, feed, fleet_scenarios, simulate, slam_config_for
from test_fleet import _Robot

MAP_FIELDS = ("ids", "n_obs", "confirmed")


def assert_same_map(loaded, saved, atol=1e-9) -> None:
    """The same landmarks in the same rows: ids, counts and flags exactly, positions (M, 2) and
    covariances (M, 2, 2) to float tolerance."""
    for name in MAP_FIELDS:
        np.testing.assert_array_equal(getattr(loaded, name), getattr(saved, name), err_msg=name)
    np.testing.assert_allclose(loaded.positions, saved.positions, rtol=0, atol=atol)
    np.testing.assert_allclose(loaded.covariances, saved.covariances, rtol=0, atol=atol)


SAVED_AT = 150          # the fleet's steps per robot before its map is saved


@pytest.fixture(scope="module")
def two_robots():
    """Two robots' 160 steps on one route and a fleet's configuration for them."""
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=SAVED_AT + 10, seed=1), 2)
    return scenarios, slam_config_for(scenarios[0], num_particles=30, seed=0)


def _saved_fleet(two_robots, path) -> FleetSlam:
    """The fleet after SAVED_AT steps of each robot, its map saved to ``path``."""
    scenarios, config = two_robots
    fleet = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    for k in range(SAVED_AT):
        for robot, scenario in enumerate(scenarios):
            feed(_Robot(fleet, robot), scenario.steps[k])
    fleet.save_map(path)
    return fleet


# ----------------------------------------------------------------- round trips
def test_a_fleet_map_loads_back_into_a_new_fleet_as_it_was_saved(tmp_path, two_robots):
    scenarios, config = two_robots
    saved = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    fleet = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    fleet.load_map(tmp_path / "fleet.npz")
    assert len(saved.landmarks()) > 10
    assert_same_map(fleet.landmarks(), saved.landmarks())
    # The file holds robot 0's pose: robot 0 relocalises there, robot 1 where it is (its start).
    with np.load(tmp_path / "fleet.npz") as arrays:
        np.testing.assert_allclose(fleet.robot(0).initial_pose, saved_pose(arrays))
    np.testing.assert_allclose(fleet.robot(1).initial_pose, scenarios[1].initial_pose)
    assert fleet.robot(0).relocalising and fleet.robot(1).relocalising


def test_a_running_fleet_reloads_its_map_and_each_robot_keeps_its_pose(tmp_path, two_robots):
    fleet = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    scenarios = two_robots[0]
    before, robot0_saved = fleet.landmarks(), fleet.pose(0).mean
    for step in scenarios[0].steps[SAVED_AT:]:          # robot 0 drives on after the save
        feed(_Robot(fleet, 0), step)
    robot1 = fleet.pose(1).mean
    fleet.load_map(tmp_path / "fleet.npz")
    assert_same_map(fleet.landmarks(), before)
    np.testing.assert_allclose(fleet.robot(0).initial_pose, robot0_saved)    # the file's pose
    np.testing.assert_allclose(fleet.robot(1).initial_pose, robot1)          # where it was
    # Each robot's time line goes on (its last stamp kept), its filter restarted.
    assert fleet.robot(0).last_stamp == pytest.approx(scenarios[0].steps[-1].stamp)
    assert fleet.robot(1).last_stamp == pytest.approx(scenarios[1].steps[SAVED_AT - 1].stamp)
    assert fleet.step_count == 0


def test_without_restore_pose_every_robot_restarts_at_its_initial_pose(tmp_path, two_robots):
    scenarios, config = two_robots
    fleet = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    fleet.load_map(tmp_path / "fleet.npz", restore_pose=False)
    for robot, scenario in enumerate(scenarios):
        np.testing.assert_allclose(fleet.pose(robot).mean, scenario.initial_pose, atol=1e-12)
        assert not fleet.robot(robot).relocalising


@pytest.mark.parametrize("restore_pose", [True, False])
def test_a_one_robot_fleet_loads_a_map_as_the_single_robot_does(tmp_path, restore_pose):
    """R = 1: the fleet's load and the single robot's load give the same estimate, bit for bit,
    and so do the 60 steps after it."""
    scenario = simulate(ScenarioConfig(n_steps=200, seed=4))
    config = slam_config_for(scenario, num_particles=30, seed=2)
    mapper = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps[:140]:
        feed(mapper, step)
    mapper.save_map(tmp_path / "single.npz")
    single = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    fleet = FleetSlam(config, [scenario.initial_pose], stamp=0.0)
    single.load_map(tmp_path / "single.npz", restore_pose)
    fleet.load_map(tmp_path / "single.npz", restore_pose)
    for step in scenario.steps[140:]:
        feed(single, step)
        feed(_Robot(fleet, 0), step)
    a, b = single.landmarks(), fleet.landmarks()
    for name in (*MAP_FIELDS, "positions", "covariances"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(single.particles()[0], fleet.particles(0)[0])


def test_a_single_robots_map_is_associated_by_every_robot_of_a_fleet(tmp_path):
    """One robot maps a whole lap without ids (every landmark), a fleet loads its file: robot 0
    goes on from where the file was saved, robot 1 starts elsewhere on the route.  Both
    relocalise and associate their observations with the file's landmarks; none is
    created again (every landmark is in the file)."""
    mapped, other = fleet_scenarios(ScenarioConfig(n_steps=700, seed=0, known_ids=False), 2)
    config = slam_config_for(mapped, num_particles=30, seed=0)
    single = OnlineEMSlam(config, initial_pose=mapped.initial_pose, stamp=0.0)
    for step in mapped.steps[:600]:
        feed(single, step)
    single.save_map(tmp_path / "single.npz")
    saved = single.landmarks()
    assert len(saved) == len(mapped.landmarks)                      # the file holds every landmark
    fleet = FleetSlam(config, [mapped.true_poses[600], other.initial_pose], stamp=None)
    fleet.load_map(tmp_path / "single.npz")
    created, associated = [0, 0], [0, 0]
    for k in range(100):
        for robot, step in enumerate((mapped.steps[600 + k], other.steps[k])):
            report = feed(_Robot(fleet, robot), step)
            created[robot] += report.n_created
            associated[robot] += report.n_associated
    # Measured (seed 0): 215 and 175 observations associated, none created.
    assert created == [0, 0] and min(associated) > 150, (created, associated)
    assert not fleet.robot(0).relocalising and not fleet.robot(1).relocalising
    assert fleet.landmarks().ids.tolist() == saved.ids.tolist()


# ----------------------------------------------------------------- refused files
def _write_garbage(path):
    path.write_bytes(b"not a map")


def _write_truncated(path):
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _write_nan_landmark(path):
    with np.load(path) as arrays:
        values = dict(arrays)
    values["theta"][0, 0] = np.nan
    np.savez(path, **values)


def _write_too_many_landmarks(path):
    with np.load(path) as arrays:
        values = dict(arrays)
    m = AssociationConfig().max_landmarks + 1       # the fleet's limit, slam_config_for's default
    rows = {name: np.repeat(values[name][:1], m, axis=0) for name in
            ("theta", "count", "inv_n", "n_obs", "confirmed", "stats", "spread", "avg_stats", "avg_count")}
    np.savez(path, **{**values, **rows, "ids": np.arange(m)})


@pytest.mark.parametrize("spoil, expected", [
    (None, "cannot read"),
    (_write_garbage, "not a complete .npz map archive"),
    (_write_truncated, "not a complete .npz map archive"),
    (_write_nan_landmark, "theta holds non-finite values"),
    (_write_too_many_landmarks, "more than the limit of"),
])
def test_a_bad_or_missing_file_is_refused_and_the_fleet_goes_on_as_before(tmp_path, two_robots, spoil, expected):
    fleet = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    path = tmp_path / ("fleet.npz" if spoil else "missing.npz")
    if spoil:
        spoil(path)
    untouched = copy.deepcopy(fleet)
    with pytest.raises(MapFileError, match=expected) as error:
        fleet.load_map(path)
    assert str(path) in str(error.value) and "\n" not in str(error.value)
    _assert_goes_on_alike(fleet, untouched, two_robots[0])


def _assert_goes_on_alike(fleet, untouched, scenarios):
    """``fleet`` is ``untouched``: the same map now and after each robot's steps after SAVED_AT."""
    assert_same_map(fleet.landmarks(), untouched.landmarks(), atol=0)
    for k in range(SAVED_AT, scenarios[0].n_steps):
        for robot, scenario in enumerate(scenarios):
            feed(_Robot(fleet, robot), scenario.steps[k])
            feed(_Robot(untouched, robot), scenario.steps[k])
    assert_same_map(fleet.landmarks(), untouched.landmarks(), atol=0)
    for robot in range(fleet.n_robots):
        np.testing.assert_array_equal(fleet.particles(robot)[0], untouched.particles(robot)[0])


def test_a_load_failing_halfway_leaves_the_fleet_as_it_was(tmp_path, two_robots, monkeypatch):
    """An error after the file was read (here robot 1's restart on the new map) puts the
    fleet's map, M-step and every robot back."""
    fleet = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    untouched = copy.deepcopy(fleet)
    original = FleetRobot.resume_from_file

    def fail_on_robot_1(robot, loaded, relocalise_at=None):
        if robot is fleet.robot(1):
            raise RuntimeError("robot 1 failed")
        original(robot, loaded, relocalise_at)

    monkeypatch.setattr(FleetRobot, "resume_from_file", fail_on_robot_1)
    with pytest.raises(RuntimeError, match="robot 1 failed"):
        fleet.load_map(tmp_path / "fleet.npz")
    monkeypatch.undo()
    _assert_goes_on_alike(fleet, untouched, two_robots[0])


# ----------------------------------------------------------------- the node's fleet estimate
def test_the_nodes_fleet_estimate_loads_a_map_for_every_robot(tmp_path, two_robots):
    from online_em_slam.ros.fleet_estimate import FleetEstimate

    scenarios, config = two_robots
    saved = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    estimate = FleetEstimate(config, [s.initial_pose for s in scenarios], ("robot1", "robot2"))
    estimate.load_map(str(tmp_path / "fleet.npz"))
    assert_same_map(estimate.landmarks(), saved.landmarks())
    for feed_view in estimate.feeds:                 # each robot's input path sees the loaded map
        assert feed_view.landmarks().ids.tolist() == saved.landmarks().ids.tolist()
        assert feed_view.relocalising


# ----------------------------------------------------------------- live: the fleet node's services
def test_the_fleet_node_loads_maps_on_start_and_on_request(ros, tmp_path, two_robots):
    """``load_map_on_start`` loads ``map_file`` into the fleet; ``~/load_map`` replaces the one map
    by a single robot's file and publishes it; a missing file is refused and the map kept;
    ``~/load_map_file`` loads ``map_file`` again."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    from online_em_slam.ros.node import OnlineEmSlamNode, latched_qos
    from test_map_files import argument, request
    from test_node import landmark_table

    scenarios, config = two_robots
    fleet = _saved_fleet(two_robots, tmp_path / "fleet.npz")
    single = OnlineEMSlam(config, initial_pose=scenarios[1].initial_pose, stamp=0.0)
    for step in scenarios[1].steps[:60]:
        feed(single, step)
    single.save_map(tmp_path / "single.npz")
    params = {"robots": ["robot1", "robot2"], "initial_poses": [float(v) for s in scenarios for v in s.initial_pose],
              "map_directory": str(tmp_path), "map_file": "fleet.npz", "load_map_on_start": True,
              "map_publish_period": 0.1}
    node = ros.node = OnlineEmSlamNode(context=ros.context, parameter_overrides=[Parameter(k, value=v)
                                                                                 for k, v in params.items()])
    ros.executor.add_node(node)
    ros.subscribe("/online_em_slam/landmarks", PointCloud2, latched_qos(), "landmarks")
    assert node.fleet_mode
    assert_same_map(node.slam.landmarks(), fleet.landmarks())

    result = ros.call(SetParameters, "load_map", request(argument(value="single"))).results[0]
    assert result.successful and str(tmp_path / "single.npz") in result.reason, result.reason
    assert_same_map(node.slam.landmarks(), single.landmarks())
    confirmed = single.landmarks(confirmed_only=True)
    assert ros.spin_until(lambda: ros.received["landmarks"] and sorted(landmark_table(ros.received["landmarks"][-1]))
                          == sorted(confirmed.ids.tolist()), 5.0)

    result = ros.call(SetParameters, "load_map", request(argument(value="missing"))).results[0]
    assert not result.successful and result.reason.startswith("could not load map:") and "missing.npz" in result.reason
    assert_same_map(node.slam.landmarks(), single.landmarks())

    assert ros.call(Trigger, "load_map_file", Trigger.Request()).success
    assert_same_map(node.slam.landmarks(), fleet.landmarks())
