"""The observation and motion models, checked against their definitions."""
import math

import numpy as np
import pytest

from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.config import MotionConfig, ObservationNoiseConfig, SensorConfig
from online_em_slam.core.models import motion
from online_em_slam.core.models.observation import (innovation, inverse_observation, landmark_jacobian,
                                             noise_covariance, noise_loglik, pose_jacobian,
                                             predict_observation, sensor_poses)


def numeric_jacobian(fun, x, eps=1e-6):
    cols = []
    for k in range(x.shape[0]):
        dx = np.zeros_like(x)
        dx[k] = eps
        diff = fun(x + dx) - fun(x - dx)
        diff[1] = wrap_angle(diff[1]) if diff.shape[0] > 1 else diff[1]
        cols.append(diff / (2 * eps))
    return np.stack(cols, axis=-1)


def test_h_is_range_and_wrapped_bearing():
    pose = np.array([1.0, 2.0, 0.5])
    landmark = np.array([4.0, 6.0])
    h = predict_observation(pose, landmark)
    assert h[0] == pytest.approx(5.0)
    assert h[1] == pytest.approx(math.atan2(4.0, 3.0) - 0.5)


def test_landmark_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    for _ in range(20):
        pose = rng.normal(size=3) * [5, 5, 3]
        landmark = pose[:2] + rng.normal(size=2) * 10
        analytic = landmark_jacobian(pose, landmark)
        numeric = numeric_jacobian(lambda th: predict_observation(pose, th), landmark)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-7)


def test_pose_jacobian_with_sensor_offset_matches_finite_differences():
    sensor = SensorConfig(offset_x=3.78, offset_y=0.5)
    rng = np.random.default_rng(1)
    for _ in range(20):
        pose = rng.normal(size=3) * [5, 5, 3]
        landmark = pose[:2] + rng.normal(size=2) * 15
        analytic = pose_jacobian(pose, landmark, sensor)
        numeric = numeric_jacobian(lambda x: predict_observation(sensor_poses(x, sensor), landmark), pose)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-6)


def test_bearings_near_pi_are_wrapped():
    pose = np.array([0.0, 0.0, 0.0])
    above = predict_observation(pose, np.array([-10.0, 1e-9]))
    below = predict_observation(pose, np.array([-10.0, -1e-9]))
    assert abs(above[1]) <= math.pi and abs(below[1]) <= math.pi
    nu = innovation(below.copy(), above)
    assert abs(nu[1]) < 1e-6
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi + 0.1) == pytest.approx(-math.pi + 0.1)


def test_inverse_observation_inverts_h():
    pose = np.array([2.0, -1.0, 2.5])
    landmark = np.array([-7.0, 3.0])
    np.testing.assert_allclose(inverse_observation(pose, predict_observation(pose, landmark)), landmark)


def test_landmark_on_top_of_sensor_gives_finite_values():
    pose = np.array([1.0, 1.0, 0.0])
    H = landmark_jacobian(pose, pose[:2])
    h = predict_observation(pose, pose[:2])
    assert np.all(np.isfinite(H)) and np.all(np.isfinite(h))


def test_mixture_likelihood_has_heavier_tails_and_responsibilities_sum_to_one():
    gaussian = ObservationNoiseConfig()
    mixture = ObservationNoiseConfig(model="mixture")
    R = noise_covariance(gaussian, np.array([10.0]))
    outlier = np.array([[5.0, 0.5]])
    ll_g, _ = noise_loglik(gaussian, outlier, R)
    ll_m, resp = noise_loglik(mixture, outlier, R)
    assert ll_m[0] > ll_g[0]
    assert resp.sum() == pytest.approx(1.0)
    assert resp[0, 1] > 0.99  # an outlier is explained by the wide component


def test_range_dependent_noise_grows_with_range():
    noise = ObservationNoiseConfig(range_growth=0.01)
    R = noise_covariance(noise, np.array([0.0, 100.0]))
    assert R[1, 0, 0] == pytest.approx((0.5 + 1.0) ** 2)
    assert R[0, 0, 0] == pytest.approx(0.25)
    assert np.all(np.linalg.eigvalsh(R) > 0)


@pytest.mark.parametrize("model,control", [("bicycle", (3.0, 0.2)), ("acfr", (2.0, 0.3)),
                                           ("unicycle", (1.5, 0.4)), ("odometry", (0.3, 0.1, 0.05))])
def test_motion_state_jacobian_matches_finite_differences(model, control):
    config = MotionConfig(model=model, wheelbase=2.83, sigma_heading=0.01)
    pose = np.array([[1.0, 2.0, 0.7]])
    mean, F, Q = motion.propagate(config, pose, np.array(control), 0.1)
    numeric = numeric_jacobian(lambda x: motion.propagate(config, x[None], np.array(control), 0.1)[0][0], pose[0])
    np.testing.assert_allclose(F[0], numeric, rtol=1e-5, atol=1e-7)
    assert np.all(np.linalg.eigvalsh(Q[0]) >= -1e-12)


def test_acfr_model_moves_laser_point_as_the_dataset_model():
    """The rear-axle pose plus the (a, b) lever arm obeys the README's laser-point ODE."""
    config = MotionConfig(model="acfr", wheelbase=2.83, encoder_offset=0.76)
    sensor = SensorConfig(offset_x=3.78, offset_y=0.5)
    v_e, alpha, dt = 3.0, 0.2, 1e-4
    pose = np.array([[0.0, 0.0, 0.4]])
    new_pose, _, _ = motion.propagate(config, pose, np.array([v_e, alpha]), dt)
    laser_rate = (sensor_poses(new_pose, sensor) - sensor_poses(pose, sensor))[0, :2] / dt
    v_c = v_e / (1 - math.tan(alpha) * 0.76 / 2.83)
    phi, a, b, L = 0.4, 3.78, 0.5, 2.83
    expected = [v_c * math.cos(phi) - v_c / L * math.tan(alpha) * (a * math.sin(phi) + b * math.cos(phi)),
                v_c * math.sin(phi) + v_c / L * math.tan(alpha) * (a * math.cos(phi) - b * math.sin(phi))]
    np.testing.assert_allclose(laser_rate, expected, rtol=1e-3)


@pytest.mark.parametrize("segments", [1, 6])
@pytest.mark.parametrize("model", ["bicycle", "acfr", "unicycle", "odometry"])
def test_batched_segments_equal_step_by_step_propagation(model, segments):
    """integrate_segments (one vectorised pass: one segment on every heading, several
    compounded in the start's heading frame and turned) = K sequential propagate calls."""
    rng = np.random.default_rng(11)
    config = MotionConfig(model=model, wheelbase=2.83, sigma_heading=0.01)
    poses = rng.normal(size=(7, 3)) * [3, 3, 2]
    a = rng.normal(size=(7, 3, 3)) * 0.1
    P = a @ a.transpose(0, 2, 1)
    width = 3 if model == "odometry" else 2
    controls = rng.normal(size=(segments, width)) * 0.3 + ([0.5, 0.0, 0.0][:width] if model == "odometry"
                                                          else [3.0, 0.0])
    dts = rng.uniform(0.01, 0.05, size=segments)
    mean, cov = poses.copy(), P.copy()
    for u, dt in zip(controls, dts):
        mean, F, Q = motion.propagate(config, mean, u, dt)
        cov = F @ cov @ F.transpose(0, 2, 1) + Q
    batch_mean, batch_cov = motion.integrate_segments(config, poses, P, controls, dts)
    np.testing.assert_allclose(batch_mean, mean, atol=1e-12)
    np.testing.assert_allclose(batch_cov, cov, atol=1e-12)


def test_noise_covariance_is_g_diag_q_g_transpose():
    rng = np.random.default_rng(3)
    G = rng.standard_normal((40, 3, 2))
    variances = rng.random(2)
    entries = [(G[:, a, 0], G[:, a, 1]) for a in range(3)]
    np.testing.assert_allclose(motion._noise_cov(entries, variances),
                               (G * variances) @ np.swapaxes(G, 1, 2), atol=1e-14)


@pytest.mark.parametrize("model", ["bicycle", "acfr", "unicycle", "odometry"])
def test_segment_factors_give_the_model_yaw_increment(model):
    """integrate_segments takes the yaw steps from a model's control factors (first entry):
    the model's own yaw increment, for controls one per row or broadcast over poses."""
    rng = np.random.default_rng(5)
    config = MotionConfig(model=model, wheelbase=2.83)
    width = 3 if model == "odometry" else 2
    controls = rng.normal(size=(4, width)) + 0.5
    dts = rng.uniform(0.01, 0.2, size=4)
    segment, _ = motion.SEGMENT_PARTS[model]
    yaw_steps = segment(config, controls[:, None, :], dts[:, None])[0][:, 0]
    moved = [motion.MODELS[model](config, np.zeros((1, 3)), u, dt)[0][0, 2] for u, dt in zip(controls, dts)]
    np.testing.assert_array_equal(yaw_steps, moved)


def test_cofactor_inverse_matches_lapack():
    from online_em_slam.core.models.gaussian import symmetric_inverse_3x3
    rng = np.random.default_rng(4)
    A = rng.standard_normal((50, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    inverse, logdet = symmetric_inverse_3x3(P)
    np.testing.assert_allclose(inverse, np.linalg.inv(P), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(P)[1], atol=1e-10)


@pytest.mark.parametrize("model", ["unicycle", "bicycle"])
def test_relative_control_noise_matches_a_perturbed_command(model):
    """sigma_u^2 = sigma^2 + (sigma_relative u)^2: the step covariance equals the spread of the
    poses reached with commands perturbed by that noise (Monte Carlo through the model's mean)."""
    rng = np.random.default_rng(5)
    config = MotionConfig(model=model, wheelbase=2.0, sigma_speed=0.05, sigma_steering=0.01,
                          sigma_speed_relative=0.2, sigma_steering_relative=0.4)
    pose, u, dt = np.array([[1.0, -2.0, 0.3]]), np.array([1.5, 0.3]), 0.05
    _, _, Q = motion.propagate(config, pose, u, dt)
    scale = config.noise_reference_period / dt
    stds = np.sqrt([(0.05 ** 2 + (0.2 * 1.5) ** 2) * scale, (0.01 ** 2 + (0.4 * 0.3) ** 2) * scale])
    n = 200_000
    commands = u + 1e-3 * stds * rng.standard_normal((n, 2))           # small: the model's linear range
    silent = MotionConfig(model=model, wheelbase=2.0, sigma_speed=0.0, sigma_steering=0.0)
    moved = motion.propagate(silent, np.repeat(pose, n, axis=0), commands, dt)[0]
    scale_of = np.sqrt(np.outer(np.diag(Q[0]), np.diag(Q[0])))     # Monte Carlo error of each entry
    np.testing.assert_allclose(np.cov(moved.T) / 1e-6 / scale_of, Q[0] / scale_of, atol=0.02)


def test_relative_noise_is_off_by_default_and_joins_the_scaled_groups():
    """Zero relative stds leave the covariance as before; motion_shape's groups of a controlled
    model are the constant and the relative parts of speed and turning, the odometry model's two."""
    config = MotionConfig(model="unicycle")
    with_zero = MotionConfig(model="unicycle", sigma_speed_relative=0.0, sigma_steering_relative=0.0)
    pose, u = np.zeros((1, 3)), np.array([1.0, 0.5])
    np.testing.assert_array_equal(motion.propagate(config, pose, u, 0.1)[2], motion.propagate(with_zero, pose, u, 0.1)[2])
    groups = motion.shape_groups(config)
    assert groups[2:] == (("sigma_speed_relative",), ("sigma_steering_relative",))
    assert len(motion.shape_groups(MotionConfig(model="odometry"))) == 2
    basis = motion.shape_basis(config)
    assert basis.sigma_steering_relative == motion.RELATIVE_UNIT
    scaled = motion.scaled_groups(basis, groups, [1.0, 4.0, 1.0, 9.0])
    assert scaled.sigma_steering == pytest.approx(2.0 * config.sigma_steering)
    assert scaled.sigma_steering_relative == pytest.approx(3.0 * motion.RELATIVE_UNIT)
