"""Issue 23 item 10: the estimate's frame against the ground truth's (offline/frames.py)."""
import math

import numpy as np
import pytest

from online_em_slam.offline import report
from online_em_slam.offline.evaluation import InitialPose, landmark_metrics, landmark_metrics_by_id, rotate_points
from online_em_slam.offline.frames import (SAME_FRAME_HEADING_DEG, check_frame, compose, inverse, points_to_truth,
                                           poses_to_truth)

TRUTH_START = InitialPose(7.0, 7.5, -2.2, 0.0, "gps", in_truth_frame=True)


def test_a_pose_from_the_ground_truth_is_its_frame():
    check = check_frame(TRUTH_START, TRUTH_START, gate=2.0)
    assert check.same_frame is True and not check.moved


def test_a_pose_near_the_truth_start_is_taken_as_given_in_its_frame():
    near = InitialPose(7.5, 7.0, -2.2 + math.radians(SAME_FRAME_HEADING_DEG - 1), 0.0, "command line")
    check = check_frame(near, TRUTH_START, gate=2.0)
    assert check.same_frame is True and not check.moved
    assert check.offset_m == pytest.approx(math.hypot(0.5, 0.5)) and "taken as given" in check.note


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (7.0, 7.5, -2.2 + math.radians(SAME_FRAME_HEADING_DEG + 1)),
                                  (10.0, 7.5, -2.2)])
def test_a_pose_elsewhere_is_another_frame_and_is_carried_by_the_start_poses(pose):
    start = InitialPose(*pose, 0.0, "params file")
    check = check_frame(start, TRUTH_START, gate=2.0)
    assert check.same_frame is False and check.moved
    assert "not the ground truth's" in check.note and "params file" in check.note and "\n" not in check.note
    # The run's start pose lands on the ground truth's start.
    np.testing.assert_allclose(poses_to_truth(check, [start.pose])[0], TRUTH_START.pose, atol=1e-12)


def test_without_a_truth_start_the_frames_are_not_checked():
    check = check_frame(InitialPose(0.0, 0.0, 0.0, 0.0, "default (0, 0, 0)"), None, gate=2.0)
    assert check.same_frame is None and not check.moved and "not checked" in check.note


def test_an_estimate_in_another_frame_scores_as_it_would_in_the_truth_frame():
    """A map and track estimated perfectly but expressed in the frame of a start at (0, 0, 0):
    scored in the truth frame it maps nothing; carried by the start poses it is exact."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(-30, 30, size=(15, 2))
    to_estimate = compose((0.0, 0.0, 0.0), [inverse(TRUTH_START.pose)])[0]   # T(estimate <- truth)
    estimate = compose(to_estimate, np.column_stack([truth, np.zeros(15)]))[:, :2]
    assert landmark_metrics(estimate, truth, gate=2.0).n_matched < 15
    check = check_frame(InitialPose(0.0, 0.0, 0.0, 0.0, "default (0, 0, 0)"), TRUTH_START, gate=2.0)
    moved = landmark_metrics(points_to_truth(check, estimate), truth, gate=2.0)
    assert moved.n_matched == 15 and moved.rmse == pytest.approx(0.0, abs=1e-9)


def test_a_map_in_a_turned_frame_counts_within_the_gate_after_its_rigid_fit():
    """Landmarks within 1 m of a map exact up to its frame (turned, shifted): few in the truth
    frame, all once the best rigid fit moves it, paired by id or by position; one landmark
    1.5 m off its place stays out either way."""
    rng = np.random.default_rng(1)
    truth = rng.uniform(-5, 5, size=(15, 2))
    estimate = rotate_points(truth, np.array(0.3)) + [1.0, -2.0]
    estimate[4] += rotate_points(np.array([[1.5, 0.0]]), np.array(0.3))[0]
    by_id = landmark_metrics_by_id(estimate, np.arange(15), truth, np.arange(15), gate=1.0)
    assert by_id.n_matched < 14 and by_id.n_matched_fitted == 14
    nearer = rotate_points(truth, np.array(0.15)) + [0.5, -0.5]       # most pairs found by position
    nearer[4] += [1.5, 0.0]
    by_position = landmark_metrics(nearer, truth, gate=1.0)
    assert by_position.n_matched < 14 and by_position.n_matched_fitted == 14


def test_the_summary_says_when_the_estimate_was_moved():
    metrics = {"method": "online_em", "n_landmarks": 15, "n_confirmed_landmarks": 15,
               "timing": {"mean_step_ms": 1.0, "p99_step_ms": 2.0, "real_time_factor": 100.0,
                          "wall_time_s": 1.25, "dataset_duration_s": 125.0}}
    plain = report.summary_line(metrics)
    other = check_frame(InitialPose(0.0, 0.0, 0.0, 0.0, "params file"), TRUTH_START, gate=2.0)
    line = report.summary_line({**metrics, "frame": other.to_dict()})
    assert "scored in the ground-truth frame after moving the estimate by its start pose" in line
    assert "frames not checked" in report.summary_line(
        {**metrics, "frame": check_frame(InitialPose(0, 0, 0, 0, "params file"), None, 2.0).to_dict()})
    same = check_frame(TRUTH_START, TRUTH_START, gate=2.0)
    assert report.summary_line({**metrics, "frame": same.to_dict()}) == plain
