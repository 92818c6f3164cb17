"""The particles' likelihood under AR(1) observation errors (core/filter/serial_errors.py),
checked against the joint Gaussian of two consecutive errors."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.stats import multivariate_normal

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.core.filter.serial_errors import LastInnovations, ar1_log_likelihood
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

C = np.array([0.8, 0.5])
R = np.array([[0.04, 0.001], [0.001, 0.0009]])


def _noise(model: str = "gaussian") -> ObservationNoiseConfig:
    return ObservationNoiseConfig(model=model, sigma_range=0.2, sigma_bearing=0.03, rho=0.001,
                                  serial_correlation=tuple(C))


def test_the_conditional_density_is_the_joint_gaussians_over_the_marginal():
    """log p(e_t | e_{t-1}) from the quasi-difference under R - C R C equals log N([e_{t-1}; e_t];
    0, [[R, R C], [C R, R]]) - log N(e_{t-1}; 0, R), the stationary AR(1)'s own joint law."""
    rng = np.random.default_rng(0)
    n = 6
    previous, current = rng.normal(0.0, 0.1, (n, 2, 2)), rng.normal(0.0, 0.1, (n, 2, 2))   # (N, P=2, 2)
    last = LastInnovations()
    last.store(4, np.array([7, 3]), previous)
    ancestors = rng.integers(0, n, n)
    got = ar1_log_likelihood(last, 5, np.array([3, 7]), current, np.stack([R, R]), ancestors, _noise(),
                             np.ones(2, dtype=bool))
    CR = np.diag(C) @ R
    joint = multivariate_normal(np.zeros(4), np.block([[R, CR.T], [CR, R]]))
    marginal = multivariate_normal(np.zeros(2), R)
    for i in range(n):
        expected = 0.0
        for p, column in ((0, 1), (1, 0)):           # landmark 3 was stored second, 7 first
            e_prev, e_now = previous[ancestors[i], column], current[i, p]
            expected += joint.logpdf(np.concatenate([e_prev, e_now])) - marginal.logpdf(e_prev)
        assert np.isclose(got[i], expected, rtol=1e-10, atol=1e-10)


def test_a_landmark_without_a_view_at_the_step_before_has_the_marginal():
    nu = np.random.default_rng(1).normal(0.0, 0.1, (3, 1, 2))
    marginal = multivariate_normal(np.zeros(2), R)
    for step, ids in ((9, np.array([5])), (5, np.array([6]))):      # not consecutive; another landmark
        last = LastInnovations()
        last.store(4, np.array([5]), np.ones((3, 1, 2)))
        got = ar1_log_likelihood(last, step, ids, nu, R[None], np.arange(3), _noise(), np.ones(1, dtype=bool))
        assert np.allclose(got, [marginal.logpdf(nu[i, 0]) for i in range(3)])


def _map_after(scenario, config, likelihood: str, serial: tuple[float, float]) -> np.ndarray:
    config = replace(config, filter=replace(config.filter, serial_likelihood=likelihood),
                     noise=replace(config.noise, serial_correlation=serial))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    return slam.landmarks().positions


def test_uncorrelated_errors_leave_the_weights_as_they_were():
    """With c = 0 (as every configuration that learns none) ar1 is the inflated likelihood: bit for
    bit; with c > 0 the setting reaches the filter (another map, still finite)."""
    scenario = simulate(ScenarioConfig(seed=0, n_steps=120))
    config = slam_config_for(scenario, num_particles=30)
    runs = [_map_after(scenario, config, likelihood, (0.0, 0.0)) for likelihood in ("inflated", "ar1")]
    assert np.array_equal(runs[0], runs[1])
    correlated = [_map_after(scenario, config, likelihood, tuple(C)) for likelihood in ("inflated", "ar1")]
    assert np.isfinite(correlated[1]).all() and not np.array_equal(correlated[0], correlated[1])


def test_correlated_errors_change_only_the_weights():
    """The innovations the M-step and the learner read are the same; the weights differ."""
    rng = np.random.default_rng(2)
    nu = rng.normal(0.0, 0.1, (4, 1, 2))
    last = LastInnovations()
    last.store(0, np.array([1]), rng.normal(0.0, 0.1, (4, 1, 2)))

    class Terms:
        log_likelihood = np.zeros(4)
    terms = Terms()
    terms.nu = nu
    last.weigh(terms, 1, np.array([1]), R[None], np.arange(4), _noise("student_t"), np.ones(1, dtype=bool))
    assert np.isfinite(terms.log_likelihood).all() and np.any(terms.log_likelihood != 0.0)
    assert last.nu is nu and last.step == 1
