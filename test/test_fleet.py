"""Fleet mode (core/fleet/): R robots, each with its own particle filter, one map."""
import itertools
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core import FleetSlam, Observations, OnlineEMSlam
from online_em_slam.core.em.observed_information import ObservedInformation
from online_em_slam.experiments.simulation import (ScenarioConfig, feed, fleet_scenarios, landmark_rmse, simulate,
                                                   slam_config_for)
from test_observed_information import PRIOR_STD, SENSOR, _feed, _problem


class _Robot:
    """One robot of a fleet with the single estimator's input methods (for simulation.feed)."""

    def __init__(self, fleet: FleetSlam, robot: int) -> None:
        self.fleet, self.robot = fleet, robot

    def add_control(self, stamp, control):
        return self.fleet.add_control(self.robot, stamp, control)

    def add_observations(self, stamp, observations):
        return self.fleet.add_observations(self.robot, stamp, observations)


def _run_fleet(scenarios, config) -> FleetSlam:
    """The robots' inputs interleaved in time, as they would arrive."""
    fleet = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    for k in range(min(s.n_steps for s in scenarios)):
        for robot, scenario in enumerate(scenarios):
            feed(_Robot(fleet, robot), scenario.steps[k])
    return fleet


def test_one_robot_fleet_is_the_single_robot_estimator():
    scenario = simulate(ScenarioConfig(n_steps=400, seed=3))
    config = slam_config_for(scenario, num_particles=50, seed=1)
    single = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(single, step)
    fleet = _run_fleet([scenario], config)
    a, b = single.landmarks(), fleet.landmarks()
    for name in ("ids", "positions", "covariances", "n_obs", "confirmed"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(single.pose().mean, fleet.pose(0).mean)
    assert np.array_equal(single.particles()[0], fleet.particles(0)[0])


def test_a_fleet_maps_better_than_each_of_its_robots():
    """Three robots from three points of the route, 500 steps each (less than a lap, so no
    robot closes its own loop): the joint map against each robot's own map."""
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=500, seed=0), 3)
    single_rmse = []
    for robot, scenario in enumerate(scenarios):
        single = OnlineEMSlam(slam_config_for(scenario, num_particles=50, seed=robot),
                              initial_pose=scenario.initial_pose, stamp=0.0)
        for step in scenario.steps:
            feed(single, step)
        lm = single.landmarks()
        single_rmse.append(landmark_rmse(lm.ids, lm.positions, scenario.landmarks))
    fleet = _run_fleet(scenarios, slam_config_for(scenarios[0], num_particles=50, seed=0))
    joint = fleet.landmarks()
    joint_rmse = landmark_rmse(joint.ids, joint.positions, scenarios[0].landmarks)
    seen = set(itertools.chain.from_iterable(step.true_ids.tolist() for s in scenarios for step in s.steps))
    assert sorted(joint.ids.tolist()) == sorted(seen)           # every landmark once
    assert joint_rmse < np.mean(single_rmse), (joint_rmse, single_rmse)
    # Measured (seed 0): joint 0.26 m; the robots alone 2.26, 3.60, 1.30 m.
    assert joint_rmse < 0.5
    for robot, scenario in enumerate(scenarios):
        assert np.hypot(*(fleet.pose(robot).mean[:2] - scenario.true_poses[-1, :2])) < 1.0


def test_unknown_ids_are_associated_against_the_shared_map():
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=400, seed=2, known_ids=False), 2)
    fleet = _run_fleet(scenarios, slam_config_for(scenarios[0], num_particles=50, seed=0))
    joint = fleet.landmarks(confirmed_only=True)
    truth = scenarios[0].landmarks
    distance = np.linalg.norm(joint.positions[:, None] - truth[None], axis=-1)
    assert len(joint) == len(truth)                                # no landmark twice
    assert len(set(distance.argmin(axis=1))) == len(truth)         # each estimate a different landmark
    assert np.all(distance.min(axis=0) < 1.5)


def test_the_joint_map_is_saved_as_a_map_file_a_single_robot_loads(tmp_path):
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=150, seed=1), 2)
    config = slam_config_for(scenarios[0], num_particles=30, seed=0)
    fleet = _run_fleet(scenarios, config)
    fleet.save_map(tmp_path / "joint.npz")
    single = OnlineEMSlam(config, initial_pose=scenarios[0].initial_pose, stamp=0.0)
    single.load_map(tmp_path / "joint.npz")
    saved, loaded = fleet.landmarks(), single.landmarks()
    np.testing.assert_array_equal(np.sort(loaded.ids), np.sort(saved.ids))
    order = np.argsort(saved.ids), np.argsort(loaded.ids)
    np.testing.assert_allclose(loaded.positions[order[1]], saved.positions[order[0]])
    with np.load(tmp_path / "joint.npz") as arrays:                 # robot 0's pose, where a reload starts
        np.testing.assert_allclose(arrays["pose"], fleet.pose(0).mean)


def _scan(landmark_id, range_, bearing=0.0):
    return Observations(np.array([range_]), np.array([bearing]), np.array([landmark_id]))


def test_a_landmark_created_by_one_robot_is_updated_by_another():
    scenario = simulate(ScenarioConfig(n_steps=1))
    config = slam_config_for(scenario, num_particles=20, seed=0)
    config = replace(config, em=replace(config.em, segment_length=1))
    fleet = FleetSlam(config, [(0.0, 0.0, 0.0), (20.0, 0.0, np.pi)], stamp=0.0)
    fleet.add_observations(0, 0.1, _scan(7, 10.0))
    created = fleet.landmarks()
    assert created.ids.tolist() == [7] and created.n_obs.tolist() == [1]
    fleet.add_observations(1, 0.1, _scan(7, 9.0))                   # robot 1 sees it at x = 11
    updated = fleet.landmarks()
    assert updated.ids.tolist() == [7] and updated.n_obs.tolist() == [2]
    assert 10.2 < updated.positions[0, 0] < 10.8                    # between the two robots' views
    assert np.all(np.linalg.eigvalsh(updated.covariances[0]) < np.linalg.eigvalsh(created.covariances[0]))


def test_a_robot_put_elsewhere_leaves_the_map_and_the_other_robots():
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=100, seed=1), 2)
    fleet = _run_fleet(scenarios, slam_config_for(scenarios[0], num_particles=30, seed=0))
    before, other = fleet.landmarks().positions, fleet.pose(0).mean
    fleet.set_pose(1, (5.0, 5.0, 0.0))
    assert np.allclose(fleet.landmarks().positions, before)
    assert np.array_equal(fleet.pose(0).mean, other)
    assert np.allclose(fleet.pose(1).mean, (5.0, 5.0, 0.0), atol=1.0)


def test_fleet_mode_refuses_what_it_does_not_support():
    config = slam_config_for(simulate(ScenarioConfig(n_steps=1)))
    with pytest.raises(ValueError, match="m_step"):
        FleetSlam(replace(config, em=replace(config.em, m_step="complete")), [(0.0, 0.0, 0.0)])
    with pytest.raises(ValueError, match="initial_poses"):
        FleetSlam(config, [(0.0, 0.0)])
    with pytest.raises(ValueError, match="robot 2"):
        FleetSlam(config, [(0.0, 0.0, 0.0)] * 2).pose(2)


# ---------------------------------------------------------------- the joint system over R key poses
@pytest.fixture(scope="module")
def problem():
    return _problem()


def test_a_segment_closes_against_its_own_robots_key_block(problem):
    """The same segment given to robot 1 of [A, B] and to robot 0 of [B, A]: the same
    system, key blocks swapped (the reordering around segment_schur)."""
    xbar, thetabar, controls, observations = problem
    other = np.array([4.0, -3.0, 1.0])
    second = ObservedInformation(SENSOR, [other, xbar[0]], PRIOR_STD, first_estimates=False)
    first = ObservedInformation(SENSOR, [xbar[0], other], PRIOR_STD, first_estimates=False)
    for est in (first, second):
        est.add_landmarks(5)
    _feed(_AsRobot(second, 1), xbar, controls, observations, 10, itertools.repeat(thetabar))
    _feed(first, xbar, controls, observations, 10, itertools.repeat(thetabar))
    swap = np.r_[3:6, 0:3, 6:second.info.shape[0]]
    assert np.allclose(second.info, first.info[np.ix_(swap, swap)], rtol=1e-12, atol=1e-9)
    assert np.allclose(second.vector, first.vector[swap], rtol=1e-12, atol=1e-9)
    assert np.array_equal(second.key_poses[1], first.key_poses[0])


def test_a_robot_without_factors_leaves_the_map_solution_alone(problem):
    """A second key pose tied to nothing but its prior changes neither theta nor the first key."""
    xbar, thetabar, controls, observations = problem
    alone = ObservedInformation(SENSOR, xbar[0], PRIOR_STD, first_estimates=False)
    fleet = ObservedInformation(SENSOR, [xbar[0], (9.0, 9.0, 0.0)], PRIOR_STD, first_estimates=False)
    for est in (alone, fleet):
        est.add_landmarks(5)
        _feed(est, xbar, controls, observations, 10, itertools.repeat(thetabar))
    theta_alone, dx_alone = alone.solve()
    theta_fleet, dx_fleet = fleet.solve()
    assert np.allclose(theta_fleet, theta_alone, atol=1e-9)
    assert np.allclose(dx_fleet[:3], dx_alone, atol=1e-9) and np.allclose(dx_fleet[3:], 0.0)


class _AsRobot:
    """An ObservedInformation fed as robot ``robot`` through the single-robot calls of _feed."""

    def __init__(self, est: ObservedInformation, robot: int) -> None:
        self.est, self.robot = est, robot

    def add_step(self, step):
        self.est.add_step(step, self.robot)

    def close_segment(self, theta):
        self.est.close_segment(theta, self.robot)
