"""Metrics of online_em_slam.offline.evaluation on hand-made cases."""
from __future__ import annotations

import math

import numpy as np
import pytest

from online_em_slam.offline.evaluation import (initial_pose_from_gps, interpolate_poses, interpolate_positions,
                                               landmark_metrics, landmark_metrics_by_id, landmark_pairs_by_id, map_error, map_error_split,
                                               map_scale_split,
                                               rigid_alignment, rigid_fit_2d, sensor_points, timing_metrics,
                                               trajectory_metrics)

TRUTH = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])


def test_perfect_landmarks_give_zero_error():
    m = landmark_metrics(TRUTH[::-1].copy(), TRUTH)
    assert m.n_matched == 4 and m.n_missed == 0 and m.n_spurious == 0
    assert m.rmse == 0.0 and m.max_error == 0.0
    assert sorted((x.true_index, x.estimate_index) for x in m.matches) == [(0, 3), (1, 2), (2, 1), (3, 0)]


def test_missed_and_spurious_landmarks_are_counted():
    est = np.array([[0.3, 0.4],        # true 0, error 0.5
                    [10.0, 0.0],       # true 1, error 0
                    [0.2, 0.0],        # duplicate near true 0: spurious
                    [50.0, 50.0]])     # far from everything: spurious
    m = landmark_metrics(est, TRUTH, gate=2.0, estimated_ids=[7, 8, 9, 10])
    assert m.n_matched == 2
    assert m.missed == [2, 3] and m.n_missed == 2
    assert m.n_spurious == 2
    # one-to-one: the closer duplicate (0.2 m) wins true landmark 0, the 0.5 m estimate is spurious
    assert sorted(m.spurious) == [7, 10]
    assert m.rmse == pytest.approx(math.sqrt((0.2 ** 2 + 0.0) / 2))
    d = m.to_dict()
    assert d["n_spurious"] == 2 and isinstance(d["matches"], list)


def test_gate_rejects_far_matches_and_empty_inputs():
    m = landmark_metrics([[3.0, 0.0]], [[0.0, 0.0]], gate=2.0)
    assert m.n_matched == 0 and m.n_missed == 1 and m.n_spurious == 1 and math.isnan(m.rmse)
    assert m.to_dict()["rmse"] is None                         # JSON-safe
    empty = landmark_metrics(np.zeros((0, 2)), TRUTH)
    assert empty.n_missed == 4 and empty.n_spurious == 0


def test_interpolation_in_time():
    t = np.array([0.0, 1.0, 3.0])
    p = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 2.0]])
    q = interpolate_positions(t, p, [-0.5, 0.0, 0.5, 2.0, 3.0, 3.5])
    assert np.isnan(q[0]).all() and np.isnan(q[5]).all()
    np.testing.assert_allclose(q[1:5], [[0, 0], [0.5, 1.0], [2.0, 2.0], [3.0, 2.0]])
    # yaw interpolated across +-pi along the short arc
    poses = np.array([[0, 0, math.pi - 0.1], [1, 0, -math.pi + 0.1]])
    mid = interpolate_poses([0.0, 1.0], poses, [0.5])[0]
    assert abs(abs(mid[2]) - math.pi) < 1e-9


def test_trajectory_error_estimate_interpolated_at_truth_times():
    t_est = np.arange(0.0, 10.01, 1.0)
    est = np.stack([t_est, np.zeros_like(t_est)], axis=1)          # x = t
    t_gt = np.array([0.5, 2.25, 7.0, 12.0])                       # 12 s is outside the estimate
    gt = np.stack([t_gt, np.full(4, 0.3)], axis=1)                # constant 0.3 m offset
    m = trajectory_metrics(t_est, est, t_gt, gt)
    assert m.alignment == "none" and m.n_ground_truth == 4 and m.n_compared == 3
    assert m.rmse == pytest.approx(0.3) and m.median == pytest.approx(0.3) and m.max == pytest.approx(0.3)
    assert m.aligned is None


def test_rigid_alignment_recovers_rotation_and_translation():
    rng = np.random.default_rng(3)
    src = rng.uniform(-20, 20, (50, 2))
    angle = 0.3
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    dst = src @ R.T + [5.0, -2.0]
    R_hat, t_hat = rigid_alignment(src, dst)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, [5.0, -2.0], atol=1e-10)
    times = np.arange(50.0)
    m = trajectory_metrics(times, src, times, dst, align=True)
    assert m.rmse > 1.0
    assert m.aligned.rmse == pytest.approx(0.0, abs=1e-9)
    assert m.aligned_rotation_deg == pytest.approx(math.degrees(angle))


def test_timing_and_real_time_factor():
    t = timing_metrics([0.001] * 99 + [0.011], dataset_duration=100.0, wall_time=4.0)
    assert t.n_steps == 100 and t.mean_step_ms == pytest.approx(1.1)
    assert t.max_step_ms == pytest.approx(11.0) and 1.0 < t.p99_step_ms <= 11.0
    assert t.real_time_factor == pytest.approx(25.0)


def test_sensor_points_and_initial_pose_from_gps_on_a_curve():
    """A vehicle driving on a circle: the GPS (sensor point) track direction is not the
    heading, but the odometry-fitted initial pose recovers the true start pose."""
    offset = (3.78, 0.5)
    true_start = np.array([12.0, -4.0, 0.7])
    radius, speed = 15.0, 3.0
    t = np.arange(0.0, 10.0, 0.05)
    # poses on a left circle starting at true_start
    yaw = true_start[2] + speed * t / radius
    cx = true_start[0] - radius * math.sin(true_start[2])
    cy = true_start[1] + radius * math.cos(true_start[2])
    poses = np.stack([cx + radius * np.sin(yaw), cy - radius * np.cos(yaw), yaw], axis=1)
    np.testing.assert_allclose(poses[0], true_start, atol=1e-12)
    gps = sensor_points(poses, offset)
    # odometry: same motion in a frame rotated and shifted arbitrarily
    a = -1.1
    Ra = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    odom = np.column_stack([poses[:, :2] @ Ra.T + [100.0, 50.0], poses[:, 2] + a])
    gps_t = t[2::4]                                 # GPS starts a little after the odometry
    est = initial_pose_from_gps(gps_t, gps[2::4], offset, start_time=0.0, odom_times=t, odom_poses=odom)
    assert est.x == pytest.approx(true_start[0], abs=1e-6)
    assert est.y == pytest.approx(true_start[1], abs=1e-6)
    assert est.yaw == pytest.approx(true_start[2], abs=1e-6)
    # without odometry: anchored at the first fix, heading = GPS track direction (biased on a curve)
    rough = initial_pose_from_gps(gps_t, gps[2::4], offset, start_time=0.0)
    np.testing.assert_allclose(sensor_points(np.array([rough.pose]), offset)[0], gps[2], atol=1e-9)
    assert abs(rough.yaw - true_start[2]) > 0.05


# --------------------------------------------------------------------------- shape and frame

def _rotation(angle: float) -> np.ndarray:
    return np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


def test_a_rigidly_moved_map_has_zero_shape_error_and_all_of_it_is_frame():
    rng = np.random.default_rng(11)
    truth = rng.uniform(-50, 50, (20, 2))
    estimated = (truth - [10.0, 5.0]) @ _rotation(0.2).T + [3.0, -7.0]
    rmse_direct = math.sqrt(np.mean(np.sum((estimated - truth) ** 2, axis=1)))
    rmse, shape, frame = map_error_split(estimated, truth)
    assert rmse == pytest.approx(rmse_direct) and rmse > 5.0
    assert shape == pytest.approx(0.0, abs=1e-9)
    assert frame == pytest.approx(rmse_direct, rel=1e-9)
    result = map_error(estimated, truth)
    assert result.rotation_deg == pytest.approx(math.degrees(-0.2))        # undoes the rotation
    np.testing.assert_allclose(estimated @ _rotation(-0.2).T + result.translation, truth, atol=1e-9)


def test_a_deformation_without_rigid_part_is_all_shape():
    # Points on a circle pushed radially by +-1 m alternately: centroid, rotation fixed.
    angles = np.linspace(0.0, 2 * math.pi, 8, endpoint=False)
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    truth = 20.0 * unit
    estimated = truth + np.where(np.arange(8) % 2 == 0, 1.0, -1.0)[:, None] * unit
    rmse, shape, frame = map_error_split(estimated, truth)
    assert rmse == pytest.approx(1.0) and shape == pytest.approx(1.0) and frame == pytest.approx(0.0, abs=1e-6)


def test_rigid_fit_matches_an_independent_least_squares_solution():
    """The closed form against scipy's iterative least squares over (angle, c) on noisy data."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(5)
    for _ in range(5):
        truth = rng.uniform(-40, 40, (15, 2))
        estimated = truth @ _rotation(rng.uniform(-1, 1)).T + rng.normal(0, 5, 2) + rng.normal(0, 1.5, (15, 2))

        def residuals(p):
            return (estimated @ _rotation(p[0]).T + p[1:] - truth).ravel()

        fit = least_squares(residuals, x0=np.zeros(3), xtol=1e-14, ftol=1e-14, gtol=1e-14)
        angle, c = rigid_fit_2d(estimated, truth)
        assert angle == pytest.approx(fit.x[0], abs=1e-7)
        np.testing.assert_allclose(c, fit.x[1:], atol=1e-6)
        rmse, shape, frame = map_error_split(estimated, truth)
        assert shape == pytest.approx(math.sqrt(np.mean(fit.fun ** 2 * 2)), rel=1e-8)
        assert rmse ** 2 == pytest.approx(shape ** 2 + frame ** 2)
        R, t = rigid_alignment(estimated, truth)                     # the SVD form agrees
        np.testing.assert_allclose(R, _rotation(float(angle)), atol=1e-9)


def test_shape_and_frame_are_vectorised_over_maps_and_handle_small_maps():
    rng = np.random.default_rng(2)
    est, tru = rng.normal(size=(4, 6, 2)), rng.normal(size=(4, 6, 2))
    batch = np.stack(map_error_split(est, tru), axis=-1)                 # (4, 3)
    loop = np.array([map_error_split(e, t) for e, t in zip(est, tru)])
    np.testing.assert_allclose(batch, loop, rtol=1e-12)
    assert rigid_fit_2d(est, tru)[1].shape == (4, 2)
    rmse, shape, frame = map_error_split([[1.0, 1.0]], [[0.0, 0.0]])      # one landmark: all frame
    assert (rmse, shape, frame) == pytest.approx((math.sqrt(2), 0.0, math.sqrt(2)))
    assert all(math.isnan(v) for v in map_error_split(np.zeros((0, 2)), np.zeros((0, 2))))
    assert map_error(np.zeros((0, 2)), np.zeros((0, 2))).to_dict()["rmse"] is None


def test_pairs_by_id_and_the_landmark_metrics_split():
    est, tru = landmark_pairs_by_id([2, -1, 0, 7], [[1, 1], [5, 5], [2, 2], [9, 9]], TRUTH)
    np.testing.assert_array_equal(est, [[1, 1], [2, 2]])
    np.testing.assert_array_equal(tru, [TRUTH[2], TRUTH[0]])
    shifted = TRUTH + [0.3, -0.4]                                       # a pure shift: 0.5 m of frame
    m = landmark_metrics(shifted, TRUTH, gate=2.0)
    assert m.rmse == pytest.approx(0.5) and m.frame_error == pytest.approx(0.5)
    assert m.shape_error == pytest.approx(0.0, abs=1e-7)
    assert math.isnan(landmark_metrics(np.zeros((0, 2)), TRUTH).shape_error)


def test_by_id_every_pair_counts_however_far():
    """Known association: the estimate of id k is scored against surveyed landmark k, so a
    landmark placed 5 m off adds 5 m to the RMSE (by position it would only be missed), two
    swapped estimates are both wrong, and an unsurveyed id is spurious."""
    ids = np.array([20, 21, 22, 23])
    est = TRUTH + [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [5.0, 0.0]]
    m = landmark_metrics_by_id(est, ids, TRUTH, ids, gate=1.0)
    assert m.paired_by == "id" and m.n_matched == 3 and m.n_spurious == 1 and m.missed == [3]
    assert m.rmse == pytest.approx(np.sqrt(25.0 / 4)) and m.max_error == pytest.approx(5.0)
    by_position = landmark_metrics(est, TRUTH, gate=1.0)
    assert by_position.n_matched == 3 and by_position.rmse == pytest.approx(0.0)      # the 5 m hidden
    swapped = landmark_metrics_by_id(TRUTH, [21, 20, 22, 23], TRUTH, ids, gate=1.0)
    assert swapped.n_matched == 2 and swapped.rmse == pytest.approx(np.sqrt(2 * 100.0 / 4))
    extra = landmark_metrics_by_id(np.vstack([TRUTH, [[50.0, 50.0]]]), [20, 21, 22, 23, 99], TRUTH, ids)
    assert extra.n_matched == 4 and extra.spurious == [99] and extra.rmse == pytest.approx(0.0)
    rotated = landmark_metrics_by_id(TRUTH @ np.array([[0.0, -1.0], [1.0, 0.0]]), ids, TRUTH, ids, gate=100.0)
    assert rotated.shape_error == pytest.approx(0.0, abs=1e-7) and rotated.frame_error == pytest.approx(rotated.rmse)


def test_map_scale_reads_a_map_too_small_and_matches_a_brute_force_similarity_fit():
    """A map 3 % too small, turned and moved, with noise: the similarity fit gives its scale and
    the shape left without it, as scipy's least squares over (log scale, angle, c) does; a rigidly
    moved map has scale 1 and the same shape either way; the metrics carry both."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(11)
    truth = rng.uniform(-6, 6, (15, 2))
    centre = truth.mean(axis=0)
    estimated = (0.97 * (truth - centre)) @ _rotation(0.4).T + centre + [1.0, -2.0] + rng.normal(0, 0.02, (15, 2))
    scale, scaled_shape = map_scale_split(estimated, truth)

    def residuals(p):
        return (np.exp(p[0]) * estimated @ _rotation(p[1]).T + p[2:] - truth).ravel()

    fit = least_squares(residuals, x0=np.zeros(4), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert scale == pytest.approx(np.exp(-fit.x[0]), rel=1e-8) and scale == pytest.approx(0.97, abs=0.005)
    assert scaled_shape == pytest.approx(math.sqrt(np.mean(fit.fun ** 2 * 2)), rel=1e-7)
    _, shape, _ = map_error_split(estimated, truth)
    assert shape > 3 * scaled_shape                                  # the rigid fit counts the size as shape
    moved = truth @ _rotation(-1.0).T + [3.0, 4.0]
    assert map_scale_split(moved, truth) == pytest.approx((1.0, 0.0), abs=1e-9)
    m = landmark_metrics_by_id(estimated, np.arange(15), truth, np.arange(15), gate=5.0)
    assert (m.map_scale, m.scaled_shape_error) == pytest.approx((scale, scaled_shape))
    assert landmark_metrics(centre + 0.98 * (truth - centre), truth, gate=1.0).map_scale == pytest.approx(0.98)
    assert all(math.isnan(v) for v in map_scale_split([[1.0, 1.0]], [[0.0, 0.0]]))
