"""Particle filter primitives, E-step statistics, smoothers and the M-step."""
import itertools

import numpy as np
import pytest
from scipy.optimize import least_squares

from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.core.models.observation import (innovation, inv_det_2x2, landmark_jacobian, noise_covariance,
                                             predict_observation)
from online_em_slam.core.filter.particles import effective_sample_size, normalize_log_weights, systematic_resample
from online_em_slam.core.weighted import weighted_pose_mean
from online_em_slam.core.em.statistics import (backward_kernel, forward_smooth, m_step,
                                            observation_statistics, paris_indices)


def test_systematic_resampling_is_unbiased():
    rng = np.random.default_rng(0)
    weights = rng.dirichlet(np.ones(7))
    counts = np.zeros(7)
    trials = 4000
    for _ in range(trials):
        counts += np.bincount(systematic_resample(weights, rng), minlength=7)
    np.testing.assert_allclose(counts / (trials * 7), weights, atol=3e-3)


def test_degenerate_log_weights_recover_to_uniform_without_nan():
    weights, _ = normalize_log_weights(np.full(5, -np.inf))
    np.testing.assert_allclose(weights, 0.2)
    weights, _ = normalize_log_weights(np.array([-1e308, -np.inf, np.nan, -2e308, -1e308]))
    assert np.all(np.isfinite(weights)) and weights.sum() == pytest.approx(1.0)
    weights, _ = normalize_log_weights(np.array([-1e5, -1e5 - 1.0]))
    assert weights[0] == pytest.approx(1 / (1 + np.exp(-1)))
    assert effective_sample_size(np.full(4, 0.25)) == pytest.approx(4.0)


def test_circular_mean_of_yaw_across_pi():
    poses = np.array([[0, 0, np.pi - 0.1], [0, 0, -np.pi + 0.1]])
    mean = weighted_pose_mean(poses, np.array([0.5, 0.5]))
    assert abs(abs(mean[2]) - np.pi) < 1e-9


def _gauss_newton_statistics(poses, ys, theta_bar, R):
    H = landmark_jacobian(poses, theta_bar[None])
    nu = innovation(ys.copy(), predict_observation(poses, theta_bar[None]))
    R_inv, _ = inv_det_2x2(R)
    return observation_statistics(H, np.broadcast_to(R_inv, H.shape), nu, theta_bar[None])


def test_m_step_with_known_poses_converges_to_the_least_squares_landmark():
    rng = np.random.default_rng(3)
    truth = np.array([12.0, -4.0])
    poses = np.column_stack([np.linspace(-10, 10, 60), np.linspace(0, 5, 60), np.linspace(-0.5, 0.5, 60)])
    noise = ObservationNoiseConfig()
    R = noise_covariance(noise, np.array(10.0))
    L = np.linalg.cholesky(R)
    ys = predict_observation(poses, truth[None]) + rng.standard_normal((60, 2)) @ L.T
    R_inv_sqrt = np.linalg.inv(L)

    def residuals(theta):
        return (innovation(ys.copy(), predict_observation(poses, theta[None])) @ R_inv_sqrt.T).ravel()

    reference = least_squares(residuals, truth + 3.0, xtol=1e-12, ftol=1e-12).x
    # Online EM pass: gamma_n = 1/n running average of the statistics, M-step each time.
    theta = truth + np.array([2.0, -2.0])
    average = np.zeros(5)
    for n in range(60):
        s = _gauss_newton_statistics(poses[n:n + 1], ys[n:n + 1], theta, R)[0]
        average += (s - average) / (n + 1)
        theta, ok = m_step(average)
        assert ok
    assert np.linalg.norm(theta - reference) < 0.05
    # Repeating the M-step over the same data is Gauss-Newton: it reaches the optimum.
    for _ in range(10):
        theta, _ = m_step(_gauss_newton_statistics(poses, ys, theta, R).mean(axis=0))
    np.testing.assert_allclose(theta, reference, atol=1e-8)


def test_m_step_refuses_singular_statistics():
    theta, ok = m_step(np.array([[0.0, 0.0, 0.0, 1.0, 1.0], [1.0, 1.0, 1.0, 0.0, 0.0]]))
    assert not ok.any() and np.all(np.isfinite(theta))


def _random_step(rng, n):
    means = rng.normal(size=(n, 3))
    a = rng.normal(size=(n, 3, 3)) * 0.5
    covs = a @ a.transpose(0, 2, 1) + 0.3 * np.eye(3)
    return means, covs


def test_forward_only_smoother_equals_brute_force_path_expectation():
    """On 3 particles over 3 steps, sum_i w_T^i tau_T^i equals the expectation of
    sum_t s(X_t) under the backward-kernel path law, enumerated path by path."""
    rng = np.random.default_rng(7)
    n, steps = 3, 3
    particles = [rng.normal(size=(n, 3))]
    log_w = [np.log(rng.dirichlet(np.ones(n)))]
    stats = [rng.normal(size=(n, 1, 5))]
    kernels = []
    tau = stats[0].copy()
    for _ in range(steps):
        means, covs = _random_step(rng, n)
        new = rng.normal(size=(n, 3))
        kernel = backward_kernel(log_w[-1], means, covs, new)
        kernels.append(kernel)
        s = rng.normal(size=(n, 1, 5))
        tau = forward_smooth(tau, kernel) + s
        particles.append(new)
        stats.append(s)
        log_w.append(np.log(rng.dirichlet(np.ones(n))))
    online = np.exp(log_w[-1]) @ tau[:, 0]
    brute = np.zeros(5)
    for path in itertools.product(range(n), repeat=steps + 1):
        prob = np.exp(log_w[-1][path[-1]])
        for t in range(steps, 0, -1):
            prob *= kernels[t - 1][path[t], path[t - 1]]
        brute += prob * sum(stats[t][path[t], 0] for t in range(steps + 1))
    np.testing.assert_allclose(online, brute, rtol=1e-10)


def test_backward_kernel_rows_follow_weight_times_transition():
    rng = np.random.default_rng(2)
    means, covs = _random_step(rng, 4)
    log_w = np.log(rng.dirichlet(np.ones(4)))
    target = rng.normal(size=(1, 3))
    kernel = backward_kernel(log_w, means, covs, target)
    from scipy.stats import multivariate_normal
    dens = np.array([np.exp(log_w[j]) * multivariate_normal(means[j], covs[j]).pdf(target[0]) for j in range(4)])
    np.testing.assert_allclose(kernel[0], dens / dens.sum(), rtol=1e-8)


def test_paris_draws_follow_the_backward_kernel():
    rng = np.random.default_rng(4)
    means, covs = _random_step(rng, 5)
    covs = covs + 2.0 * np.eye(3)
    log_w = np.log(rng.dirichlet(np.ones(5)))
    target = rng.normal(size=(1, 3)) * 0.3
    kernel = backward_kernel(log_w, means, covs, target)[0]
    draws = paris_indices(log_w, means, covs, np.repeat(target, 4000, axis=0), 2, rng)
    freq = np.bincount(draws.ravel(), minlength=5) / draws.size
    np.testing.assert_allclose(freq, kernel, atol=0.02)


def test_smoothers_are_pieces_named_by_the_configuration():
    """One interface, picked by filter.smoother: each piece is the kernel it names."""
    from types import SimpleNamespace

    from online_em_slam.core.config import SMOOTHERS, FilterConfig
    from online_em_slam.core.em.statistics import SMOOTHERS as PIECES, make_smoother, paris_smooth
    assert tuple(PIECES) == SMOOTHERS
    rng = np.random.default_rng(5)
    n = 6
    means, covs = _random_step(rng, n)
    data = SimpleNamespace(log_weights_prev=np.log(rng.dirichlet(np.ones(n))), transition_means=means,
                           transition_covs=covs, particles=rng.normal(size=(n, 3)),
                           ancestors=rng.integers(0, n, n))
    tau = rng.normal(size=(n, 4, 5))
    kernel = backward_kernel(data.log_weights_prev, means, covs, data.particles)
    expected = {"forward": forward_smooth(tau, kernel), "ancestry": tau[data.ancestors],
                "paris": paris_smooth(tau, paris_indices(data.log_weights_prev, means, covs, data.particles,
                                                         3, np.random.default_rng(9)))}
    for name in SMOOTHERS:
        smoother = make_smoother(FilterConfig(smoother=name, paris_draws=3), np.random.default_rng(9))
        np.testing.assert_array_equal(smoother.update(tau, data), expected[name])
        assert smoother.whole_table == (name == "ancestry")
