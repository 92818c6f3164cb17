"""Marginal-SLAM baseline: the map by recursive maximum likelihood (baselines/marginal_slam.py).

The piece is fed FilterStepData built directly, so the poses are known exactly
(no motion noise): on that static-pose problem the recursive ML map must reach
the least-squares landmark, as the EM M-step does.
"""
import numpy as np
import pytest
from scipy.optimize import least_squares

from online_em_slam.baselines.gtsam_batch import dead_reckoning
from online_em_slam.baselines.marginal_slam import MarginalSlam, RecursiveMLMapUpdate
from online_em_slam.core.config import ObservationNoiseConfig, SensorConfig, SlamConfig
from online_em_slam.core.em.complete import CompleteDataEM
from online_em_slam.core.em.step import FilterStepData
from online_em_slam.core.mapping.landmarks import LandmarkTable
from online_em_slam.core.models.observation import (innovation, inv_det_2x2, landmark_jacobian, noise_covariance,
                                                    predict_observation, sensor_poses)
from online_em_slam.experiments.simulation import ScenarioConfig, feed, landmark_rmse, simulate, slam_config_for

N = 6


def _step_data(step, particles, weights, rows, y, theta, log_weights_prev=None, transition_std=1e-3):
    """FilterStepData of one scan seen from ``particles`` (N, 3) under the map ``theta``."""
    n = particles.shape[0]
    R = np.broadcast_to(noise_covariance(ObservationNoiseConfig(), np.array(10.0)), (len(rows), 2, 2)).copy()
    sensor = sensor_poses(particles, SensorConfig())
    nu = innovation(np.broadcast_to(y, (n,) + y.shape).copy(), predict_observation(sensor[:, None], theta[rows][None]))
    H = landmark_jacobian(sensor[:, None], theta[rows][None])
    R_inv, _ = inv_det_2x2(R)
    uniform = np.full(n, 1.0 / n)
    return FilterStepData(
        step=step, particles=particles, weights=weights,
        log_weights_prev=np.log(uniform) if log_weights_prev is None else log_weights_prev,
        prior_weights=uniform, ancestors=np.arange(n), transition_means=particles.copy(),
        transition_covs=np.broadcast_to(np.eye(3) * transition_std ** 2, (n, 3, 3)).copy(),
        rows=np.asarray(rows), y=y, R=R, sensor=sensor, nu=nu, H=H, precision=np.broadcast_to(R_inv, H.shape).copy(),
        motion_mean=particles[0].copy(), motion_jacobian=np.eye(3), motion_cov=np.eye(3) * 1e-6)


@pytest.fixture(scope="module")
def static_problem():
    """60 known poses, noisy range-bearing observations of one landmark, its least-squares fit."""
    rng = np.random.default_rng(3)
    truth = np.array([12.0, -4.0])
    poses = np.column_stack([np.linspace(-10, 10, 60), np.linspace(0, 5, 60), np.linspace(-0.5, 0.5, 60)])
    R = noise_covariance(ObservationNoiseConfig(), np.array(10.0))
    L = np.linalg.cholesky(R)
    ys = predict_observation(poses, truth[None]) + rng.standard_normal((60, 2)) @ L.T
    whiten = np.linalg.inv(L)

    def residuals(theta):
        return (innovation(ys.copy(), predict_observation(poses, theta[None])) @ whiten.T).ravel()

    reference = least_squares(residuals, truth + 3.0, xtol=1e-12, ftol=1e-12).x
    return truth, poses, ys, reference


def _run_static(piece, poses, ys, start, passes):
    """Every particle at the known pose: the filter's law is a point mass on the true path."""
    table = LandmarkTable()
    table.add(start[None], np.array([0]), 0)
    piece.add_landmarks(1)
    weights = np.full(N, 1.0 / N)
    for k in range(passes * len(poses)):
        pose, y = poses[k % len(poses)], ys[k % len(poses)][None]
        piece.update(_step_data(k, np.tile(pose, (N, 1)), weights, [0], y, table.theta), table)
    return table.theta[0].copy()


def test_recursive_ml_with_known_poses_converges_to_the_least_squares_landmark(static_problem):
    truth, poses, ys, reference = static_problem
    start = truth + np.array([2.0, -2.0])
    config = SlamConfig()
    rng = np.random.default_rng(0)
    # gamma_n = 1/n: with the preconditioner Ibar^-1 this is recursive least squares, one pass.
    one_pass = _run_static(RecursiveMLMapUpdate(config, N, rng, step_size_exponent=1.0), poses, ys, start, 1)
    config.em.step_size_exponent = 1.0
    em_one_pass = _run_static(CompleteDataEM(config, N, rng), poses, ys, start, 1)
    assert np.linalg.norm(one_pass - reference) < 0.01
    # With known poses the preconditioned gradient step is the online-EM recursion:
    # A_n theta_n = b_n with both statistics blended by gamma_n is
    # theta_n = theta_{n-1} + gamma_n A_n^-1 H^T P nu, even with h re-linearised each time.
    np.testing.assert_allclose(one_pass, em_one_pass, atol=1e-9)
    # The online-EM step size n^-0.8: the stochastic approximation settles on the
    # least-squares point as the steps decay (the data are cycled).
    config.em.step_size_exponent = 0.8
    many = _run_static(RecursiveMLMapUpdate(config, N, rng), poses, ys, start, 30)
    em_many = _run_static(CompleteDataEM(config, N, rng), poses, ys, start, 30)
    assert np.linalg.norm(many - reference) < 0.01
    np.testing.assert_allclose(many, em_many, atol=1e-9)


def test_first_step_is_the_gauss_newton_step_of_the_observation(static_problem):
    """n = 1, gamma = 1: theta + (H^T P H)^-1 H^T P nu, the landmark that explains y exactly to first order."""
    truth, poses, ys, _ = static_problem
    piece = RecursiveMLMapUpdate(SlamConfig(), N, np.random.default_rng(0))
    start = truth + np.array([0.3, -0.2])
    table = LandmarkTable()
    table.add(start[None], np.array([0]), 0)
    piece.add_landmarks(1)
    data = _step_data(0, np.tile(poses[0], (N, 1)), np.full(N, 1.0 / N), [0], ys[0][None], table.theta)
    piece.update(data, table)
    H, nu = data.H[0, 0], data.nu[0, 0]
    np.testing.assert_allclose(table.theta[0], start + np.linalg.solve(H, nu), atol=1e-9)


def test_score_increment_reweights_the_past_scores_of_unseen_landmarks():
    """Fisher's identity with smoothing: an observation of landmark 1 that favours
    particle 0 moves landmark 0 along particle 0's accumulated score."""
    particles = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])        # far apart: the kernel is the identity
    theta = np.array([[10.0, 10.0], [20.0, -5.0]])
    piece = RecursiveMLMapUpdate(SlamConfig(), 2, np.random.default_rng(0))
    table = LandmarkTable()
    table.add(theta.copy(), np.array([0, 1]), 0)
    piece.add_landmarks(2)
    piece.alpha[:, 0] = [[1.0, 0.0], [-1.0, 0.0]]
    piece.differing[0] = True
    piece.count[:] = 1
    piece.information[:] = np.eye(2)
    y = predict_observation(sensor_poses(particles[0], SensorConfig()), theta[1])[None]
    data = _step_data(5, particles, np.array([0.9, 0.1]), [1], y, table.theta, np.log([0.5, 0.5]))
    piece.update(data, table)
    # G_t - G_{t-1} = (0.9 - 0.1) - 0 along x; gamma = 1, Ibar = I.
    np.testing.assert_allclose(table.theta[0], theta[0] + [0.8, 0.0], atol=1e-9)
    # A landmark whose score is the same in every particle does not move when unseen.
    piece.alpha[:, 0] = [[2.0, 1.0], [2.0, 1.0]]
    before = table.theta[0].copy()
    piece.update(_step_data(6, particles, np.array([0.9, 0.1]), [1], y, table.theta, np.log([0.5, 0.5])), table)
    np.testing.assert_allclose(table.theta[0], before)


def test_marginal_slam_maps_the_simulated_scenario_and_saves_its_map(tmp_path):
    scenario = simulate(ScenarioConfig(seed=1, n_steps=300))
    config = slam_config_for(scenario, num_particles=40, seed=1)
    slam = MarginalSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    lm = slam.landmarks()
    assert len(lm) > 5 and np.all(np.isfinite(lm.positions)) and np.all(np.isfinite(lm.covariances))
    _, dr = dead_reckoning(scenario, config, len(scenario.landmarks))
    seen = np.isfinite(dr[:, 0])
    dr_rmse = float(np.sqrt(np.mean(np.sum((dr[seen] - scenario.landmarks[seen]) ** 2, axis=1))))
    assert landmark_rmse(lm.ids, lm.positions, scenario.landmarks) < dr_rmse
    path = str(tmp_path / "map.npz")
    slam.save_map(path)
    loaded = MarginalSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    loaded.load_map(path)
    np.testing.assert_allclose(loaded.landmarks().positions, lm.positions)
    np.testing.assert_allclose(loaded.landmarks().covariances, lm.covariances)
