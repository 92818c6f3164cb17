"""Robot-to-robot barcode reads in the fleet batch (offline/robot_reads.py, offline/extra_poses.py,
datasets/mrclam/dataset.py load_robot_reads, datasets/mrclam/fleet_batch.py), on tiny synthetic problems.

(a) The loader keeps a robot's reads of the others (subjects 1-5) and drops as the landmark loader;
    a read's stamp is its image's scan stamp in the bag.
(b) Extra pose variables split the motion between scans without changing it.
(c) The read's prediction and its Jacobians (with and without a sensor lever arm).
(d) The GTSAM factor has zero error at the true poses and pulls a misplaced robot back; a misread
    is gated.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.baselines.gtsam_batch import compose
from online_em_slam.core.config import MotionConfig, SensorConfig, SlamConfig
from online_em_slam.core.types import Observations
from online_em_slam.datasets.mrclam.dataset import load_robot_reads
from online_em_slam.offline.batch import collect_problem
from online_em_slam.offline.robot_reads import (FleetReads, ReadFactors, fleet_reads, pose_variables, read_factors,
                                                read_measurement, squared_distances)
from online_em_slam.pipeline.inputs import CONTROL, OBSERVATIONS

OBSERVER, OBSERVED = np.array([0.0, 0.0, 0.3]), np.array([2.0, 1.0, -1.0])
R_READ = np.diag([0.05 ** 2, 0.01 ** 2])


def _true_read(offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(range, bearing) of OBSERVED's centre from OBSERVER's sensor at ``offset``, from first principles."""
    c, s = np.cos(OBSERVER[2]), np.sin(OBSERVER[2])
    sensor = OBSERVER[:2] + np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]])
    d = OBSERVED[:2] - sensor
    bearing = np.arctan2(d[1], d[0]) - OBSERVER[2] - offset[2]
    return np.array([np.hypot(*d), np.arctan2(np.sin(bearing), np.cos(bearing))])


def _one_read(y, observer=0, observed=1) -> ReadFactors:
    return ReadFactors(np.array([observer]), np.array([observed]), np.array([y]), R_READ[None], np.array([0]))


# --------------------------------------------------------------------------- (a) loader

BARCODES = "# subject barcode\n1 5\n2 14\n3 41\n6 72\n"
MEASUREMENTS = {1: "# t barcode range bearing\n-1.0 14 2.0 0.1\n0.5 14 2.0 0.1\n0.5 72 3.0 0.2\n"
                   "1.0 41 nan 0.0\n1.5 5 1.0 0.0\n2.0 41 2.5 -0.3\n20.0 14 1.0 0.0\n",
                2: "# t barcode range bearing\n0.5 5 2.1 3.0\n0.7 72 1.0 0.0\n"}


def _write_dataset(directory):
    directory.mkdir()
    (directory / "Barcodes.dat").write_text(BARCODES)
    (directory / "Landmark_Groundtruth.dat").write_text("6 1.0 2.0 0.0 0.0\n")
    odometry = np.column_stack([0.02 * np.arange(501), np.full(501, 0.1), np.zeros(501)])
    for robot, text in MEASUREMENTS.items():
        np.savetxt(directory / f"Robot{robot}_Odometry.dat", odometry, fmt="%.6g")
        (directory / f"Robot{robot}_Measurement.dat").write_text(text)
    return directory


def test_loader_keeps_the_reads_of_other_robots(tmp_path):
    reads = load_robot_reads(_write_dataset(tmp_path / "MRCLAM_Dataset1"), robots=(1, 2))
    np.testing.assert_allclose(reads.times, [0.5, 0.5, 2.0])
    assert reads.observer.tolist() == [1, 2, 1] and reads.observed.tolist() == [2, 1, 3]
    np.testing.assert_allclose(reads.range, [2.0, 2.1, 2.5])
    np.testing.assert_allclose(reads.bearing, [0.1, 3.0, -0.3])
    assert reads.drops == Counter(before_odometry=1, after_odometry=1, own_barcode=1, bad_range=1, bad_bearing=0)
    cut = load_robot_reads(tmp_path / "MRCLAM_Dataset1", robots=(1,), seconds=1.0)
    assert len(cut) == 1 and cut.truncated == 4


def test_fleet_reads_keep_the_bag_s_robots_and_span():
    y = np.ones((4, 2))
    fleet = fleet_reads([1.0, 2.0, 3.0, 9.0], ["robot1", "robot2", "robot1", "robot1"],
                        ["robot2", "robot4", "robot2", "robot2"], y, ["robot1", "robot2"], [(0.0, 5.0), (0.5, 8.0)])
    assert fleet.stamps.tolist() == [1.0, 3.0] and fleet.observer.tolist() == [0, 0] and fleet.observed.tolist() == [1, 1]
    assert fleet.not_in_the_bag == Counter(robot_not_in_fleet=1, outside_the_bag_span=1)
    assert fleet.stamps_of(1).tolist() == [1.0, 3.0]


def test_read_stamps_are_the_bag_s_message_stamps():
    """A read shares its image's time: its stamp must equal the scan's stamp exactly to find its pose variable."""
    from types import SimpleNamespace

    from online_em_slam.bag.bagio import message_stamp
    from online_em_slam.datasets.mrclam.convert import to_stamp_ns
    from online_em_slam.datasets.mrclam.fleet_batch import bag_stamps

    times = np.array([0.02, 11.56, 599.98, 1234.5])
    for t, stamp in zip(times, bag_stamps(times)):
        sec, nanosec = divmod(int(to_stamp_ns(t)), 1_000_000_000)
        assert stamp == message_stamp(SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(
            sec=sec, nanosec=nanosec))), 0)


# --------------------------------------------------------------------------- (b) extra pose variables

def _config() -> SlamConfig:
    return SlamConfig(motion=MotionConfig(model="unicycle"))


def _events():
    """Controls every 0.1 s turning on a circle, scans at 1.0 and 2.0 s."""
    events = [(CONTROL, 0.1 * k, np.array([0.5, 0.3])) for k in range(31)]
    for t in (1.0, 2.0):
        events.append((OBSERVATIONS, t, Observations(np.array([3.0]), np.array([0.2]), np.array([7]))))
    return sorted(events, key=lambda e: (e[1], e[0] == OBSERVATIONS))


def _compounded_covariance(a, cov_a, b, cov_b) -> np.ndarray:
    """Covariance (3, 3) of the motion a (+) b in a's origin frame: a ~ (a, cov_a) there, b ~ (b, cov_b)
    in a's end frame (first order: a's heading error swings b's translation)."""
    c, s = np.cos(a[2]), np.sin(a[2])
    J_a = np.array([[1.0, 0.0, -s * b[0] - c * b[1]], [0.0, 1.0, c * b[0] - s * b[1]], [0.0, 0.0, 1.0]])
    J_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return J_a @ cov_a @ J_a.T + J_b @ cov_b @ J_b.T


def test_extra_pose_variables_split_the_motion_between_scans():
    plain = collect_problem(_events(), _config())
    split = collect_problem(_events(), _config(), extra_poses=[1.5, 1.0, 1.5, -1.0, 9.0])
    assert plain.stamps.tolist() == [0.0, 1.0, 2.0]
    assert split.stamps.tolist() == [0.0, 1.0, 1.5, 2.0]           # 1.0: the scan's own variable
    assert split.skipped["extra_pose_before_motion"] == 1 and split.skipped["extra_pose_after_inputs"] == 1
    assert split.obs_pose.tolist() == [1, 3] and plain.obs_pose.tolist() == [1, 2]
    assert pose_variables(split.stamps, np.array([1.5, 1.45, 2.0])).tolist() == [2, -1, 3]
    # On a control step's boundary the two parts compound to the whole exactly; the covariance
    # differs by the extra variable's step jitter (1 mm, 1e-4 rad), no more.
    np.testing.assert_allclose(compose(split.increments[1], split.increments[2]), plain.increments[1], atol=1e-12)
    joined = _compounded_covariance(split.increments[1], split.motion_covariances[1], split.increments[2],
                                    split.motion_covariances[2])
    np.testing.assert_allclose(joined, plain.motion_covariances[1], atol=2.1e-6)
    assert not np.allclose(joined, plain.motion_covariances[1], atol=1e-9)


def test_extra_pose_variable_inside_a_control_step():
    plain = collect_problem(_events(), _config())
    split = collect_problem(_events(), _config(), extra_poses=[1.45])
    assert split.stamps.tolist() == [0.0, 1.0, 1.45, 2.0]
    # The unicycle step is a mid-point rule: a 0.1 s step cut in two ends ~1e-6 m elsewhere.
    np.testing.assert_allclose(compose(split.increments[1], split.increments[2]), plain.increments[1], atol=1e-5)


def test_read_factors_join_the_two_robots_chains():
    problems = [collect_problem(_events(), _config(), extra_poses=[1.45]),
                collect_problem(_events(), _config(), extra_poses=[1.45, 1.7])]
    reads = FleetReads(np.array([1.45, 1.7, 2.5]), np.array([0, 1, 0]), np.array([1, 0, 1]),
                       np.array([[2.0, 0.1], [1.0, 0.0], [1.0, 0.0]]))
    factors = read_factors(reads, problems, (0, 4), [_config(), _config()])
    assert factors.observer.tolist() == [2] and factors.observed.tolist() == [4 + 2]
    assert factors.left_out == Counter(no_pose_variable=2)      # robot 0 has no variable at 1.7 nor at 2.5
    assert factors.R[0, 0, 0] == pytest.approx(_config().noise.sigma_range ** 2)


# --------------------------------------------------------------------------- (c) prediction

@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.3, -0.1, 0.2)])
def test_read_prediction_and_jacobians(offset):
    h, H_a, H_b = read_measurement(OBSERVER, OBSERVED, offset)
    np.testing.assert_allclose(h, _true_read(offset), atol=1e-12)
    for pose, H, which in ((OBSERVER, H_a, 0), (OBSERVED, H_b, 1)):
        numeric = np.zeros((2, 3))
        for i in range(3):
            xi = np.zeros(3)
            xi[i] = 1e-6
            moved = compose(pose, xi)                             # X Exp(xi): body-frame perturbation
            args = (moved, OBSERVED) if which == 0 else (OBSERVER, moved)
            numeric[:, i] = (read_measurement(*args, offset)[0] - h) / 1e-6
        np.testing.assert_allclose(H, numeric, atol=1e-5)


def test_misread_stands_out():
    poses = np.stack([OBSERVER, OBSERVED])
    good, bad = _one_read(_true_read()), _one_read(_true_read() + [1.0, 0.0])
    assert squared_distances(poses, good)[0] == pytest.approx(0.0, abs=1e-18)
    assert squared_distances(poses, bad)[0] == pytest.approx(1.0 / 0.05 ** 2)
    assert bad.subset(np.array([False]), "gated").left_out == Counter(gated=1)


# --------------------------------------------------------------------------- (d) GTSAM

@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.3, -0.1, 0.2)])
def test_gtsam_read_factor_is_zero_at_the_truth_and_pulls_a_robot_back(offset):
    gtsam = pytest.importorskip("gtsam")
    from online_em_slam.baselines.gtsam_batch import symbols
    from online_em_slam.offline.robot_reads import gtsam_factors

    X = symbols(gtsam)[0]
    sensor = replace(SensorConfig(), offset_x=offset[0], offset_y=offset[1], offset_yaw=offset[2])
    factor = gtsam_factors(gtsam, _one_read(_true_read(offset)), sensor)[0]
    truth = gtsam.Values()
    truth.insert(X(0), gtsam.Pose2(*OBSERVER))
    truth.insert(X(1), gtsam.Pose2(*OBSERVED))
    assert factor.error(truth) < 1e-20

    graph = gtsam.NonlinearFactorGraph()
    graph.add(factor)
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*OBSERVER), gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)))
    misplaced = OBSERVED + [0.4, -0.3, 0.0]                      # a weak prior where the robot is not
    graph.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(*misplaced),
                                     gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1e-3]))))
    start = gtsam.Values()
    start.insert(X(0), gtsam.Pose2(*OBSERVER))
    start.insert(X(1), gtsam.Pose2(*misplaced))
    solved = gtsam.LevenbergMarquardtOptimizer(graph, start).optimize().atPose2(X(1))
    assert np.hypot(solved.x() - OBSERVED[0], solved.y() - OBSERVED[1]) < 0.01
