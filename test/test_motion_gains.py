"""The calibration of the motion input learned online (core/em/noise/motion_gains.py): the models'
gains, the filter's sensitivity of the mean pose to them against finite differences of a
fresh integration, the statistic (G) against pose errors simulated step by step, and the
learner recovering a steering gain of 0.7 on the simulated scenario."""
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core.config import MotionConfig, NoiseLearningConfig, replace_section
from online_em_slam.core.em.noise.motion_gains import MotionGains, gain_statistic, transported
from online_em_slam.core.em.noise.motion_noise import MotionSteps, compound
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.models.motion import GAIN_NAMES, integrate_segments, propagate, scaled_noise
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for


@pytest.mark.parametrize("model, control, scaled", [("unicycle", [1.0, 0.3], [0.9, 0.6]),
                                                    ("bicycle", [3.0, 0.2], [2.7, 0.4]),
                                                    ("odometry", [0.3, 0.02, 0.1], [0.27, 0.018, 0.2])])
def test_the_gains_multiply_the_motion_input(model, control, scaled):
    config = MotionConfig(model=model)
    calibrated = replace(config, translation_gain=0.9, rotation_gain=2.0)
    pose = np.array([[1.0, 2.0, 0.5]])
    for got, expected in zip(propagate(calibrated, pose, np.array(control), 0.1),
                             propagate(config, pose, np.array(scaled), 0.1)):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)
    many = np.array([control, control])
    np.testing.assert_allclose(integrate_segments(calibrated, pose, np.zeros((1, 3, 3)), many, np.full(2, 0.1))[0],
                               integrate_segments(config, pose, np.zeros((1, 3, 3)), np.array([scaled, scaled]),
                                                  np.full(2, 0.1))[0], rtol=1e-12)


def test_a_turn_in_place_takes_the_in_place_gain_and_a_turn_while_driving_the_rotation_gain():
    config = MotionConfig(model="unicycle")
    calibrated = replace(config, translation_gain=0.9, rotation_gain=0.6, rotation_in_place_gain=1.1)
    pose, zero = np.array([[1.0, 2.0, 0.5]]), np.zeros((1, 3, 3))
    controls, dts = np.array([[0.0, 0.5], [0.2, 0.5], [0.0, -0.3]]), np.full(3, 0.1)
    expected = controls * np.array([[0.9, 1.1], [0.9, 0.6], [0.9, 1.1]])
    np.testing.assert_allclose(integrate_segments(calibrated, pose, zero, controls, dts)[0],
                               integrate_segments(config, pose, zero, expected, dts)[0], rtol=1e-12)


def test_scaled_noise_scales_the_covariance_and_keeps_the_config_at_one():
    config = MotionConfig(model="unicycle")
    pose, u = np.array([[0.0, 0.0, 0.3]]), np.array([1.0, 0.2])
    np.testing.assert_allclose(propagate(scaled_noise(config, 3.0, 3.0), pose, u, 0.1)[2],
                               3.0 * propagate(config, pose, u, 0.1)[2], rtol=1e-12)
    assert scaled_noise(config) is config


def test_the_filters_sensitivity_to_the_gains_is_the_finite_difference_of_a_fresh_integration():
    """Controls of one filter step integrated in two flushes (a pose query in between): the
    carried sensitivity equals (mean(gain + h) - mean(gain - h)) / 2h over all of them at once."""
    scenario = simulate(ScenarioConfig(seed=2, n_steps=30))
    config = slam_config_for(scenario, num_particles=5)
    config = replace_section(config, motion=replace(config.motion, model="unicycle"),   # it can turn in place
                             noise_learning=NoiseLearningConfig(enabled=True,
                                                                learn=("motion_gains", "motion_gain_in_place")))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    slam.add_observations(0.0, scenario.steps[0].observations())
    start = slam._motion.pose.copy()
    controls = [(0.1 * k, np.array([3.0 if k % 3 else 0.0, 0.1 + 0.05 * k])) for k in range(1, 9)]  # 2 in place
    for k, (t, u) in enumerate(controls):
        slam.add_control(t, u)
        if k == 3:
            slam.pose()                                      # a first flush
    slam.pose()
    dts = np.diff([0.0] + [t for t, _ in controls])[1:]
    us = np.array([u for _, u in controls])[:-1]
    expected = np.empty((3, len(GAIN_NAMES)))
    learned = replace(config.motion, rotation_in_place_gain=1.0)   # learned, a gain of its own
    for j, name in enumerate(GAIN_NAMES):
        ends = [integrate_segments(replace(learned, **{name: 1.0 + h}), start[None], np.zeros((1, 3, 3)),
                                   us, dts)[0][0] for h in (1e-5, -1e-5)]
        expected[:, j] = (ends[0] - ends[1]) / 2e-5
    assert np.all(np.abs(expected[2, 1:]) > 0.01)          # both turning gains turn the track
    np.testing.assert_allclose(slam._motion.sensitivity, expected, rtol=1e-5, atol=1e-8)


def test_transported_is_the_sum_of_phi_times_terms():
    rng = np.random.default_rng(0)
    F, terms = np.eye(3) + 0.1 * rng.normal(size=(4, 3, 3)), rng.normal(size=(4, 3, 2))
    def phi(k):                                    # F_3 ... F_{k+1}
        product = np.eye(3)
        for j in range(3, k, -1):
            product = product @ F[j]
        return product
    expected = sum(phi(k) @ terms[k] for k in range(4))
    np.testing.assert_allclose(transported(F, terms), expected, rtol=1e-12)
    # the same carrying as compound's residuals
    steps = MotionSteps(terms[..., 0], F, np.zeros((4, 3, 3)), np.zeros((4, 3, 3)), np.zeros((4, 3, 3)))
    np.testing.assert_allclose(compound(steps)[0], transported(F, terms[..., :1])[:, 0], rtol=1e-12)


@pytest.mark.parametrize("in_use", [(1.0, 1.0), (1.2, 0.6)])
def test_the_gain_statistic_finds_the_true_gains_whatever_gains_are_in_use(in_use):
    """Pose errors simulated step by step from gains in use kappa_t while the truth is (0.9, 0.7):
    e_k = F_k e_{k-1} + D_k (kappa* - kappa_t) + w_k, the scan nu = H_x e_L + v.  N^-1 h is
    kappa* within 4 of its standard errors."""
    rng = np.random.default_rng(6)
    L, n, truth, gains = 5, 3000, np.array([0.9, 0.7]), np.array(in_use)
    F = np.eye(3) + 0.1 * rng.normal(size=(L + 1, 3, 3))
    roots = 0.05 * rng.normal(size=(L + 1, 3, 2))
    Q = roots @ roots.transpose(0, 2, 1)
    J = np.broadcast_to(1e-6 * np.eye(3), (L + 1, 3, 3)).copy()
    P0 = np.diag([0.01, 0.02, 0.001])
    D = 0.3 * rng.normal(size=(L + 1, 3, 2))
    steps = MotionSteps(np.zeros((L + 1, 3)), F, Q, J, np.broadcast_to(P0, (L + 1, 3, 3)).copy())
    H_x = rng.normal(size=(3, 2, 3))
    noise = np.broadcast_to(np.diag([0.01, 0.001]), (3, 2, 2)).copy()
    e = rng.multivariate_normal(np.zeros(3), P0, size=n)
    for k in range(1, L + 1):
        e = e @ F[k].T + D[k] @ (truth - gains) + rng.multivariate_normal(np.zeros(3), Q[k] + J[k], size=n)
    nu = np.einsum("pij,nj->npi", H_x, e) + rng.multivariate_normal(np.zeros(2), noise[0], size=(n, 3))
    learner = MotionGains(1.0, window=1)
    for row in nu:
        learner.blend(gain_statistic(steps, D, H_x, row, noise, 1.0, gains))
    estimate, error = learner.estimate()
    assert np.all(np.abs(estimate - truth) < 4 * error) and np.all(error < 0.02)


def test_the_learner_finds_a_steering_gain_of_0_7_on_the_simulation():
    """The vehicle steers 0.7 times the commanded angle: the learned rotation gain is within 5 %
    of 0.7 and comes into use, the translation gain within 5 % of 1."""
    scenario = simulate(ScenarioConfig(seed=3, n_steps=1000))
    config = replace_section(slam_config_for(scenario, num_particles=30, seed=0), noise_learning=NoiseLearningConfig(
        enabled=True, learn=("motion_gains",), replay_warmup=False))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    for step in scenario.steps:
        slam.add_control(step.control_stamp, step.control / np.array([1.0, 0.7]))
        slam.add_observations(step.stamp, step.observations())
    learned = slam.learned_noise()
    assert learned["motion_gains"][1] == pytest.approx(0.7, rel=0.05) and learned["motion_gains_in_use"][1]
    assert learned["motion_gains"][0] == pytest.approx(1.0, rel=0.05)


def test_a_gain_is_used_once_known_or_once_the_data_reject_the_one_in_use():
    """Known to the tolerance (0.03), or the estimate more than three standard errors from the
    gain in use: 0.64 +- 0.05 against the configured 1.0 is used, 0.95 +- 0.05 is not yet."""
    from online_em_slam.core.em.noise.motion_gains import known

    in_use = np.ones(2)
    np.testing.assert_array_equal(known(np.array([0.64, 0.95]), in_use, np.array([0.05, 0.05]), 0.03),
                                  [True, False])
    np.testing.assert_array_equal(known(np.array([0.99, 1.2]), in_use, np.array([0.02, 0.2]), 0.03),
                                  [True, False])


def test_a_gain_no_window_excited_stays_and_the_others_are_solved_without_it():
    """Three gains, the third (turning in place) never excited (its sensitivity zero): its
    estimate is NaN with an infinite error, the other two are the two-gain solution."""
    rng = np.random.default_rng(2)
    L = 4
    steps = MotionSteps(np.zeros((L + 1, 3)), np.broadcast_to(np.eye(3), (L + 1, 3, 3)).copy(),
                        np.broadcast_to(1e-3 * np.eye(3), (L + 1, 3, 3)).copy(), np.zeros((L + 1, 3, 3)),
                        np.broadcast_to(1e-3 * np.eye(3), (L + 1, 3, 3)).copy())
    D2 = 0.3 * rng.normal(size=(L + 1, 3, 2))
    D3 = np.concatenate([D2, np.zeros((L + 1, 3, 1))], axis=-1)
    H_x, noise = rng.normal(size=(2, 2, 3)), np.broadcast_to(np.diag([0.01, 0.001]), (2, 2, 2)).copy()
    two, three = MotionGains(1.0, window=1), MotionGains(1.0, window=1, n_gains=3)
    for _ in range(50):
        nu = 0.1 * rng.normal(size=(2, 2))
        two.blend(gain_statistic(steps, D2, H_x, nu, noise, 1.0, np.ones(2)))
        three.blend(gain_statistic(steps, D3, H_x, nu, noise, 1.0, np.ones(3)))
    (g2, e2), (g3, e3) = two.estimate(), three.estimate()
    np.testing.assert_allclose(g3[:2], g2, rtol=1e-10)
    np.testing.assert_allclose(e3[:2], e2, rtol=1e-10)
    assert np.isnan(g3[2]) and e3[2] == np.inf


def test_an_in_place_gain_of_zero_is_the_rotation_gain_and_learning_it_needs_motion_gains():
    config = replace(MotionConfig(model="unicycle"), translation_gain=0.9, rotation_gain=0.6)
    pose, zero, dts = np.array([[1.0, 2.0, 0.5]]), np.zeros((1, 3, 3)), np.full(2, 0.1)
    controls = np.array([[0.0, 0.5], [0.2, 0.5]])
    np.testing.assert_array_equal(integrate_segments(config, pose, zero, controls, dts)[0],
                                  integrate_segments(replace(config, rotation_in_place_gain=0.6), pose, zero,
                                                     controls, dts)[0])
    with pytest.raises(ValueError, match="motion_gain_in_place"):
        NoiseLearningConfig(enabled=True, learn=("motion_gain_in_place",)).validate()
