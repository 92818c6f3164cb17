"""The shared input contract (core/inputs.py) and the core's defences against hostile inputs
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
    slam = OnlineEMSlam(SlamConfig())
    positions = np.array([[0.0, 0.0], [0.5, 0.0], [5.0, 0.0], [5.2, 0.1], [20.0, 0.0]])
    kept, index = slam._dedupe_new(positions, np.arange(5))
    np.testing.assert_array_equal(index, [0, 2, 4])
