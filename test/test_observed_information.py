"""The observed-information M-step against an independent batch Gauss-Newton step.

The batch step is built here without the module's Jacobians: finite differences
of the nonlinear motion and observation models over every pose and landmark,
whitened residuals, and scipy's least-squares solver for the normal equations.
"""
import itertools

import numpy as np
import pytest
from scipy.linalg import cholesky, lstsq

from online_em_slam.core.models import motion
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.config import MotionConfig, SensorConfig
from online_em_slam.core.models.observation import predict_observation, sensor_poses
from online_em_slam.core.em.observed_information import ObservedInformation
from online_em_slam.core.em.segment_factors import StepFactors, motion_residual

SENSOR = SensorConfig(offset_x=0.6, offset_y=-0.2, offset_yaw=0.05, max_range=40.0)
MOTION = MotionConfig(model="bicycle", wheelbase=2.5, sigma_speed=0.3, sigma_steering=0.03)
R = np.array([[0.3 ** 2, 0.002], [0.002, 0.02 ** 2]])
PRIOR_STD = np.array([0.2, 0.3, 0.05])
DT = 0.5


def _problem(seed=3, steps=50, n_landmarks=5):
    """Linearisation points (perturbed truth), controls and observations of a small run."""
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(-15, 25, (n_landmarks, 2))
    controls = np.column_stack([np.full(steps, 3.0), 0.15 * np.sin(np.arange(steps) / 6.0)])
    truth = [np.array([0.0, 0.0, 0.3])]
    for u in controls:
        truth.append(motion.propagate(MOTION, truth[-1][None], u, DT)[0][0])
    truth = np.array(truth)
    xbar = truth + rng.normal(0, [0.4, 0.4, 0.03], truth.shape)
    thetabar = landmarks + rng.normal(0, 0.8, landmarks.shape)
    observations = []
    for t in range(1, steps + 1):
        seen = np.flatnonzero(rng.random(n_landmarks) < 0.6)
        y = predict_observation(sensor_poses(truth[t], SENSOR)[None], landmarks[seen])
        y = y + rng.multivariate_normal([0, 0], R, seen.size)
        observations.append((seen, y))
    return xbar, thetabar, controls, observations


def _transition(pose, u):
    mean, F, Q = motion.propagate(MOTION, pose[None], u, DT)
    return mean[0], F[0], Q[0] + motion.step_jitter(MOTION)


def _feed(est, xbar, controls, observations, segment_length, maps):
    """Every step's factors; a segment closes every ``segment_length`` steps at the next map of ``maps``."""
    for t in range(1, len(xbar)):
        predicted, F, Q = _transition(xbar[t - 1], controls[t - 1])
        rows, y = observations[t - 1]
        precision = np.broadcast_to(np.linalg.inv(R), (rows.size, 2, 2)).copy()
        est.add_step(StepFactors(xbar[t], F, motion_residual(predicted, xbar[t]),
                                 Q, rows, y, precision))
        if t % segment_length == 0:
            est.close_segment(next(maps))
    return est


def _estimator(xbar, controls, observations, segment_length, n_landmarks, thetabar):
    est = ObservedInformation(SENSOR, xbar[0], PRIOR_STD, first_estimates=False)
    est.add_landmarks(n_landmarks)
    _feed(est, xbar, controls, observations, segment_length, itertools.repeat(thetabar))
    est.close_segment(thetabar)
    return est


def _batch_gauss_newton_step(xbar, thetabar, controls, observations, x0):
    """One GN step of the whole problem, Jacobians by central differences."""
    n_pose = xbar.shape[0]

    def residuals(z):
        poses = z[:3 * n_pose].reshape(n_pose, 3)
        theta = z[3 * n_pose:].reshape(-1, 2)
        out = [cholesky(np.diag(1 / PRIOR_STD ** 2)) @ _wrapped(poses[0] - x0)]
        for t in range(1, n_pose):
            _, _, Q = _transition(xbar[t - 1], controls[t - 1])   # covariance fixed at the linearisation
            predicted = motion.propagate(MOTION, poses[t - 1][None], controls[t - 1], DT)[0][0]
            out.append(cholesky(np.linalg.inv(Q)) @ _wrapped(predicted - poses[t]))
            rows, y = observations[t - 1]
            h = predict_observation(sensor_poses(poses[t], SENSOR)[None], theta[rows])
            for k in range(rows.size):
                diff = h[k] - y[k]
                diff[1] = wrap_angle(diff[1])
                out.append(cholesky(np.linalg.inv(R)) @ diff)
        return np.concatenate(out)

    z0 = np.concatenate([xbar.ravel(), thetabar.ravel()])
    e0 = residuals(z0)
    J = np.empty((e0.size, z0.size))
    for i in range(z0.size):
        step = np.zeros_like(z0)
        step[i] = 1e-6
        J[:, i] = (residuals(z0 + step) - residuals(z0 - step)) / 2e-6
    delta = lstsq(J.T @ J, -J.T @ e0)[0]
    z = z0 + delta
    return z[3 * n_pose:].reshape(-1, 2), z[3 * (n_pose - 1):3 * n_pose]


def _wrapped(d):
    d = d.copy()
    d[2] = wrap_angle(d[2])
    return d


@pytest.fixture(scope="module")
def problem():
    return _problem()


def test_marginalised_solve_equals_one_batch_gauss_newton_step(problem):
    xbar, thetabar, controls, observations = problem
    est = _estimator(xbar, controls, observations, segment_length=len(xbar), n_landmarks=5,
                     thetabar=thetabar)
    theta, dx_key = est.solve()
    theta_batch, last_pose_batch = _batch_gauss_newton_step(xbar, thetabar, controls, observations, xbar[0])
    assert np.max(np.abs(theta - theta_batch)) < 1e-6
    assert np.max(np.abs(_wrapped(est.key_pose + dx_key - last_pose_batch))) < 1e-6


def test_segment_length_does_not_change_the_solution(problem):
    """Integrating poses out every K steps is exact when the linearisation point is the same."""
    xbar, thetabar, controls, observations = problem
    whole = _estimator(xbar, controls, observations, len(xbar), 5, thetabar).solve()
    for k in (1, 7):
        theta, dx = _estimator(xbar, controls, observations, k, 5, thetabar).solve()
        assert np.max(np.abs(theta - whole[0])) < 1e-8
        assert np.max(np.abs(dx - whole[1])) < 1e-8


def test_pruning_a_landmark_between_segments_leaves_the_others_unchanged(problem):
    xbar, thetabar, controls, observations = problem
    est = _estimator(xbar, controls, observations, 10, 5, thetabar)
    theta_before, dx_before = est.solve()
    keep = np.array([True, True, False, True, True])
    est.keep_landmarks(keep)
    theta_after, dx_after = est.solve()
    assert est.n_landmarks == 4
    assert np.max(np.abs(theta_after - theta_before[keep])) < 1e-8
    assert np.max(np.abs(dx_after - dx_before)) < 1e-8


def test_moving_the_key_pose_keeps_the_same_minimiser(problem):
    xbar, thetabar, controls, observations = problem
    est = _estimator(xbar, controls, observations, 10, 5, thetabar)
    theta, dx = est.solve()
    absolute = est.key_pose + dx
    est.move_key(np.array([0.3, -0.2, 0.01]))
    theta_moved, dx_moved = est.solve()
    assert np.max(np.abs(theta_moved - theta)) < 1e-9
    assert np.max(np.abs(est.key_pose + dx_moved - absolute)) < 1e-9


def test_marginal_covariances_are_the_blocks_of_the_inverse(problem):
    xbar, thetabar, controls, observations = problem
    est = _estimator(xbar, controls, observations, 10, 5, thetabar)
    cov = est.landmark_covariances()
    full = np.linalg.inv(est.info)
    assert np.allclose(cov[2], full[3 + 4:3 + 6, 3 + 4:3 + 6])
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def _gauge_residual(first_estimates: bool, problem) -> float:
    """|info N| / |info| |N| for the rotation about the origin, at the first estimates,
    after segments linearised at a map that moves between them."""
    xbar, thetabar, controls, observations = problem
    est = ObservedInformation(SENSOR, xbar[0], np.full(3, 1e6), first_estimates=first_estimates)
    est.add_landmarks(5)
    rng = np.random.default_rng(7)
    maps = [thetabar.copy()]
    for _ in range((len(xbar) - 1) // 10):
        maps.append(maps[-1] + rng.normal(0, 0.3, thetabar.shape))    # the map moves between segments
    _feed(est, xbar, controls, observations, 10, iter(maps))
    theta = maps[-1]
    points = est.landmark_first if first_estimates else theta
    key = est.key_first
    null = np.concatenate([[-key[1], key[0], 1.0], np.column_stack([-points[:, 1], points[:, 0]]).ravel()])
    return float(np.linalg.norm(est.info @ null) / (np.linalg.norm(est.info) * np.linalg.norm(null)))


def test_first_estimate_jacobians_keep_the_map_rotation_unobserved(problem):
    """FEJ: a rotation of every pose and landmark stays in the null space of the
    factors, so only the first-pose prior fixes the map's orientation."""
    assert _gauge_residual(True, problem) < 1e-9
    assert _gauge_residual(False, problem) > 1e-4


def test_restarting_the_key_pose_keeps_the_map_and_unties_the_pose(problem):
    """A teleport (initial-pose message): the map's solution is unchanged, the new key
    pose is tied to nothing but its prior."""
    xbar, thetabar, controls, observations = problem
    est = _estimator(xbar, controls, observations, 10, 5, thetabar)
    theta_before, _ = est.solve()
    est.restart_key(np.array([3.0, -2.0, 0.5]), np.array([0.2, 0.2, 0.05]))
    theta_after, dx = est.solve()
    assert np.max(np.abs(theta_after - theta_before)) < 1e-8
    assert np.max(np.abs(dx)) < 1e-12
    assert not est.info[:3, 3:].any()
