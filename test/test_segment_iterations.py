"""A segment's poses and landmarks relinearised before its poses are integrated out (``em.segment_iterations``).

Checked against scipy's nonlinear least squares of the same problem, built here from the
motion and observation models (not the module's Jacobians): one segment over the whole run,
the first pose's prior, the motion factors f(x_{t-1}, u) - x_t and the observation factors
y - h(x_t, theta_k), every pose and landmark nonlinear (first-estimate Jacobians off).  The
motion noise is isotropic in position, so its covariance does not depend on the heading the
iterations move.
"""
import numpy as np
import pytest
from scipy.optimize import least_squares

from online_em_slam.core.config import EMConfig, SlamConfig
from online_em_slam.core.em.observed import ObservedInformationEM
from online_em_slam.core.em.observed_covariance import ObservedCovariance
from online_em_slam.core.em.segment_factors import StepFactors, motion_residual
from online_em_slam.core.models import motion
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.models.observation import predict_observation, sensor_poses
from test_observed_information import DT, MOTION, PRIOR_STD, R, SENSOR, _problem

Q = np.diag([0.05 ** 2, 0.05 ** 2, 0.01 ** 2])


def _store(problem, iterations, close=True):
    xbar, thetabar, controls, observations = problem
    store = ObservedCovariance(SENSOR, xbar[0], PRIOR_STD, first_estimates=False, iterations=iterations)
    store.add_landmarks(thetabar.shape[0])
    for t in range(1, len(xbar)):
        predicted, F, _ = motion.propagate(MOTION, xbar[t - 1][None], controls[t - 1], DT)
        rows, y = observations[t - 1]
        precision = np.broadcast_to(np.linalg.inv(R), (rows.size, 2, 2)).copy()
        store.add_step(StepFactors(xbar[t], F[0], motion_residual(predicted[0], xbar[t]), Q, rows, y, precision))
    if close:
        store.close_segment(thetabar)
    return store


def _optimum(problem):
    """(theta, last pose) minimising the problem's whitened residuals (scipy, from xbar, thetabar)."""
    xbar, thetabar, controls, observations = problem
    n = xbar.shape[0]
    prior, motion_w, obs_w = np.diag(1 / PRIOR_STD), np.linalg.cholesky(np.linalg.inv(Q)).T, \
        np.linalg.cholesky(np.linalg.inv(R)).T

    step_of = np.concatenate([np.full(rows.size, t) for t, (rows, _) in enumerate(observations, start=1)])
    rows = np.concatenate([rows for rows, _ in observations])
    y = np.concatenate([y for _, y in observations])

    def residuals(z):
        poses, theta = z[:3 * n].reshape(n, 3), z[3 * n:].reshape(-1, 2)
        predicted = motion.propagate(MOTION, poses[:-1], controls, DT)[0]
        moved = predicted - poses[1:]
        moved[:, 2] = wrap_angle(moved[:, 2])
        seen = predict_observation(sensor_poses(poses[step_of], SENSOR), theta[rows]) - y
        seen[:, 1] = wrap_angle(seen[:, 1])
        return np.concatenate([prior @ _wrapped(poses[0] - xbar[0]), (moved @ motion_w.T).ravel(),
                               (seen @ obs_w.T).ravel()])

    z = least_squares(residuals, np.concatenate([xbar.ravel(), thetabar.ravel()]), xtol=1e-14, ftol=1e-14,
                      gtol=1e-14).x
    return z[3 * n:].reshape(-1, 2), z[3 * (n - 1):3 * n]


def _wrapped(d):
    d = d.copy()
    d[2] = wrap_angle(d[2])
    return d


def _errors(store, optimum):
    theta, dx_key = store.solve()
    return (np.max(np.abs(theta - optimum[0])),
            np.max(np.abs(_wrapped(store.key_pose + dx_key - optimum[1]))))


def test_iterated_segment_reaches_the_nonlinear_optimum():
    problem = _problem(seed=5, steps=30)
    xbar = problem[0].copy()
    xbar[:, 2] += np.random.default_rng(1).normal(0.0, 0.15, xbar.shape[0])    # headings far off: nonlinear
    problem = (xbar,) + problem[1:]
    optimum = _optimum(problem)
    store = _store(problem, 20)
    once, iterated = _errors(_store(problem, 1), optimum), _errors(store, optimum)
    assert max(iterated) < 1e-5
    assert np.allclose(store.key_pose, xbar[-1], atol=1e-12)   # the correction is relative to the filter's pose
    assert min(once) > 100 * max(iterated)            # the one linearisation is visibly off


def test_one_iteration_is_the_linearised_close():
    """iterations 1 closes as the store always did: the segment linearised once and folded."""
    problem = _problem(seed=5, steps=30)
    closed = _store(problem, 1)
    folded = ObservedCovariance(SENSOR, problem[0][0], PRIOR_STD, first_estimates=False)
    folded.add_landmarks(problem[1].shape[0])
    folded.segments = _store_steps(problem)
    folded.fold(folded.segment_system(problem[1]))
    for a, b in zip(closed.solve(), folded.solve()):
        assert np.array_equal(a, b)


def _store_steps(problem):
    """The buffered steps of :func:`_store`, before any close."""
    store = _store(problem, 1, close=False)
    return store.segments


def test_iterations_need_the_covariance_form():
    with pytest.raises(ValueError, match="covariance"):
        EMConfig(segment_iterations=3, map_form="information").validate()


def test_the_fixed_lag_is_for_one_robot():
    config = SlamConfig(em=EMConfig(segment_iterations=5))
    assert ObservedInformationEM(config, np.zeros(3)).system.iterations == 5
    assert ObservedInformationEM(config, np.zeros((2, 3))).system.iterations == 1
