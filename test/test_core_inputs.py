"""The shared input contract (core/filter/input_contract.py) and the core's defences against hostile inputs
(issue 12, defects 5 and 7): each test fails on the code before them."""
import tracemalloc

import numpy as np
import pytest

from online_em_slam.baselines.ekf_slam import EkfSlam
from online_em_slam.core import Observations, OnlineEMSlam, SlamConfig


def _odometry_config():
    config = SlamConfig()
    config.motion.model = "odometry"
    config.filter.num_particles = 50
    return config


def _drive(slam, poses, t0=0.0, dt=0.1):
    for k, pose in enumerate(poses):
        slam.add_odometry(t0 + k * dt, pose)


@pytest.mark.parametrize("estimator", [OnlineEMSlam, EkfSlam])
def test_one_absurd_odometry_pose_is_dropped_and_motion_is_kept(estimator):
    slam = estimator(_odometry_config())
    _drive(slam, [(0.1 * k, 0.0, 0.0) for k in range(10)])
    slam.add_odometry(1.0, (1e300, 0.0, 0.0))
    _drive(slam, [(1.0 + 0.1 * k, 0.0, 0.0) for k in range(1, 11)], t0=1.1)
    pose = slam.pose().mean
    assert np.all(np.isfinite(pose))
    assert abs(pose[0] - 2.0) < 0.3 and abs(pose[1]) < 0.3
    assert slam.drops["implausible_odometry"] == 1


def test_a_confirmed_jump_of_the_odometry_frame_becomes_the_new_reference():
    slam = OnlineEMSlam(_odometry_config())
    _drive(slam, [(0.1 * k, 0.0, 0.0) for k in range(10)])
    _drive(slam, [(500.0 + 0.1 * k, 0.0, 0.0) for k in range(10)], t0=1.0)    # a driver restart
    pose = slam.pose().mean
    assert slam.drops["odometry_jump_reset"] == 1
    assert abs(pose[0] - (0.9 + 0.6)) < 0.3      # no 500 m jump; the motion after the reset is used


@pytest.mark.parametrize("control", [(1e300, 0.0), (3.0, 2.0), (-80.0, 0.1)])
def test_physically_impossible_controls_are_dropped(control):
    slam = OnlineEMSlam(SlamConfig())
    slam.add_control(0.0, (2.0, 0.0))
    assert not slam.add_control(0.5, control)
    slam.add_control(1.0, (2.0, 0.0))
    pose = slam.pose().mean
    assert np.all(np.isfinite(pose)) and abs(pose[0] - 2.0) < 0.5
    assert slam.drops["implausible_control"] == 1


def test_a_huge_unknown_id_cloud_is_capped_and_costs_little_memory():
    config = SlamConfig()
    config.filter.num_particles = 20
    config.sensor.max_range = 1e4
    slam = OnlineEMSlam(config)
    rng = np.random.default_rng(0)
    n = 8000
    tracemalloc.start()
    report = slam.add_observations(0.0, Observations(rng.uniform(1, 5, n), rng.uniform(-3, 3, n)))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert report.dropped["too_many_observations"] == n - config.association.max_observations_per_scan
    assert peak < 300e6            # the n x n x 2 distance array alone was 1 GB
    assert len(slam.landmarks()) <= config.association.max_observations_per_scan


def test_merging_of_new_landmarks_keeps_the_first_of_close_pairs():
    from online_em_slam.core.filter.association import merge_close
    positions = np.array([[0.0, 0.0], [0.5, 0.0], [5.0, 0.0], [5.2, 0.1], [20.0, 0.0]])
    kept, index = merge_close(positions, np.arange(5), 2.0 * SlamConfig().noise.sigma_range)
    np.testing.assert_array_equal(index, [0, 2, 4])


def _run_with_reset(m_step, reset):
    from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for
    scenario = simulate(ScenarioConfig(seed=0, n_steps=300))
    config = slam_config_for(scenario)
    config.em.m_step = m_step
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps[:200]:
        feed(slam, step)
    before = slam.landmarks()
    if reset:
        slam.set_pose(slam.pose().mean + np.array([0.3, -0.2, 0.02]), std=(0.5, 0.5, 0.05))
    for step in scenario.steps[200:]:
        feed(slam, step)
    return slam, before, scenario


@pytest.mark.parametrize("m_step", ["observed", "complete"])
def test_set_pose_moves_the_robot_and_keeps_the_map(m_step):
    """A pose reset (as from /initialpose) 0.36 m off: the map is kept, no landmark is
    duplicated, and the run ends about where the same run without the reset does."""
    slam, before, scenario = _run_with_reset(m_step, True)
    reference, _, _ = _run_with_reset(m_step, False)
    after = slam.landmarks()
    assert set(before.ids) <= set(after.ids) and len(set(after.ids)) == len(after)
    assert np.all(np.isfinite(after.positions))
    truth = scenario.true_poses[-1][:2]
    assert (np.linalg.norm(slam.pose().mean[:2] - truth)
            < np.linalg.norm(reference.pose().mean[:2] - truth) + 1.0)
    with pytest.raises(ValueError):
        slam.set_pose((0.0, np.nan, 0.0))
