"""The noise law's responsibilities with the landmark's covariance given the robot's pose.

`em.responsibilities_with_map_uncertainty` (docs/METHOD.md, "Responsibilities and the map's
uncertainty"): the landmarks' covariances given the key pose are checked against the joint
Gaussian's conditional computed independently (the inverse of the precision's block), in both
forms of the stored Gaussian, and the responsibilities against the noise law on the widened
innovation covariance.
"""
import numpy as np
import pytest

from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.core.em.segment_factors import given_key
from online_em_slam.core.filter.observation_terms import observation_terms
from online_em_slam.core.models.observation import component_precision_weight, landmark_jacobian, noise_loglik
from test_observed_covariance import _both
from test_observed_information import _problem


def _conditional_by_precision(full: np.ndarray, key: np.ndarray, landmark: np.ndarray) -> np.ndarray:
    """Sigma_l|key as the inverse of the landmark block of the (key, landmark) marginal's precision."""
    idx = np.concatenate([key, landmark])
    precision = np.linalg.inv(full[np.ix_(idx, idx)])
    return np.linalg.inv(precision[key.size:, key.size:])


def test_given_key_is_the_gaussian_conditional():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(9, 9))
    S = A @ A.T + np.eye(9)
    key, landmarks = np.arange(3), [np.arange(3, 5), np.arange(5, 7), np.arange(7, 9)]
    got = given_key(S[np.ix_(key, key)], np.stack([S[np.ix_(l, key)] for l in landmarks]),
                    np.stack([S[np.ix_(l, l)] for l in landmarks]))
    for g, l in zip(got, landmarks):
        assert np.allclose(g, _conditional_by_precision(S, key, l), rtol=1e-10, atol=1e-12)


def test_both_forms_give_the_conditional_of_the_stored_gaussian():
    info, cov = _both(_problem(), 10)
    info.solve()                                   # the information form answers from its last solve
    full = np.linalg.inv(info.info)
    rows = np.array([4, 0, 2])
    expected = [_conditional_by_precision(full, np.arange(3), 3 + 2 * r + np.arange(2)) for r in rows]
    for form in (info, cov):
        assert np.allclose(form.covariances_given_key(rows), expected, rtol=1e-7, atol=1e-12)
    # pruning keeps the others' Gaussian: the same conditionals by the new rows, without a solve
    keep = np.array([True, False, True, True, True])
    for form in (info, cov):
        form.keep_landmarks(keep)
    new_rows = np.array([3, 1])                    # old rows 4 and 2
    for form in (info, cov):
        assert np.allclose(form.covariances_given_key(new_rows), [expected[0], expected[2]], rtol=1e-7, atol=1e-12)
    # a landmark not in the stored Gaussian yet has none
    for form in (info, cov):
        form.add_landmarks(1)
        assert np.isnan(form.covariances_given_key(np.array([4]))).all()


@pytest.mark.parametrize("model", ["student_t", "mixture"])
def test_responsibilities_come_from_the_widened_innovation_covariance(model):
    rng = np.random.default_rng(0)
    noise = ObservationNoiseConfig(model=model, sigma_range=0.1, sigma_bearing=0.01)
    theta = np.array([[4.0, 1.0], [2.0, -3.0]])
    sensor = np.column_stack([rng.normal(0, 0.05, 6), rng.normal(0, 0.05, 6), rng.normal(0, 0.02, 6)])
    y = np.array([[4.2, 0.6], [3.6, -1.0]])        # the first far off: a loop closing, or an outlier
    R = np.array([np.diag([0.01, 1e-4])] * 2)
    given = np.array([np.diag([0.3, 0.3]), np.full((2, 2), np.nan)])
    weighting = np.ones(2, dtype=bool)
    plain = observation_terms(y, R, theta, sensor, noise, weighting, None)
    widened = observation_terms(y, R, theta, sensor, noise, weighting, None, given)
    H = landmark_jacobian(sensor[:, None, :], theta[None])
    S = R[0] + H[:, 0] @ given[0] @ np.swapaxes(H[:, 0], -1, -2)
    _, resp = noise_loglik(noise, widened.nu[:, :1], S[:, None])
    R_inv = np.linalg.inv(R)
    assert np.allclose(widened.precision[:, 0], R_inv[0] * component_precision_weight(noise, resp)[:, 0, None, None])
    assert np.array_equal(widened.precision[:, 1], plain.precision[:, 1])       # none given: R alone
    assert np.trace(widened.precision[0, 0]) > 3 * np.trace(plain.precision[0, 0])   # not an outlier now
    assert np.array_equal(widened.log_likelihood, plain.log_likelihood)         # the particles' weights stay


def test_gaussian_noise_is_left_alone():
    noise = ObservationNoiseConfig(model="gaussian", sigma_range=0.1, sigma_bearing=0.01)
    theta, sensor = np.array([[4.0, 1.0]]), np.zeros((3, 3))
    y, R = np.array([[4.5, 0.5]]), np.array([np.diag([0.01, 1e-4])])
    plain = observation_terms(y, R, theta, sensor, noise, np.ones(1, dtype=bool), None)
    widened = observation_terms(y, R, theta, sensor, noise, np.ones(1, dtype=bool), None, np.array([np.eye(2)]))
    assert np.array_equal(widened.precision, plain.precision)


def test_a_run_with_it_on_maps_the_same_in_both_forms_of_the_stored_gaussian():
    """Over a simulated run with outliers under Student-t noise, the covariance form and the
    information form (answering from its last solve's factor) give the same responsibilities."""
    from dataclasses import replace

    from online_em_slam.core import OnlineEMSlam
    from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

    scenario = simulate(ScenarioConfig(seed=4, n_steps=300, outlier_probability=0.1))
    maps = []
    for form in ("covariance", "information"):
        config = slam_config_for(scenario, num_particles=30)
        config = replace(config, noise=replace(config.noise, model="student_t", dof=4.0),
                         em=replace(config.em, responsibilities_with_map_uncertainty=True, map_form=form))
        slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
        for step in scenario.steps:
            feed(slam, step)
        maps.append(slam.landmarks())
    (a, b) = maps
    assert np.array_equal(a.ids, b.ids) and len(a.ids) >= 10
    assert np.allclose(a.positions, b.positions, atol=1e-6)
