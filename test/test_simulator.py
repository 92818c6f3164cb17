"""Tests of the seeded simulator of the seed experiment (online_em_slam/simulation.py)."""
import math
import time

import numpy as np
import pytest

from online_em_slam.core.models.observation import innovation, noise_covariance, predict_observation
from online_em_slam.experiments.simulation import (ScenarioConfig, Scenario, feed, landmark_rmse, simulate,
                                                   slam_config_for)


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return simulate(ScenarioConfig(seed=3))


def _residuals(s: Scenario) -> np.ndarray:
    """y - h(X_true, theta_true) for every observation of the run (bearing wrapped)."""
    out = []
    for k, step in enumerate(s.steps, start=1):
        clean = predict_observation(s.true_poses[k][None, :], s.landmarks[step.true_ids])
        out.append(innovation(np.stack([step.ranges, step.bearings], 1), clean))
    return np.concatenate(out)


def test_shapes_and_stamps(scenario):
    T = scenario.config.n_steps
    assert scenario.true_poses.shape == (T + 1, 3)
    assert scenario.landmarks.shape == (20, 2)
    assert scenario.controls.shape == scenario.true_controls.shape == (T, 2)
    assert len(scenario.steps) == T
    for k, step in enumerate(scenario.steps):
        assert step.stamp == pytest.approx((k + 1) * 0.2)
        assert step.control_stamp == pytest.approx(k * 0.2)
        n = len(step.ranges)
        assert step.bearings.shape == step.ids.shape == step.true_ids.shape == (n,)
        assert np.array_equal(step.ids, step.true_ids)
    assert np.all(np.isfinite(scenario.true_poses))


def test_fast_and_deterministic():
    start = time.perf_counter()
    a = simulate(ScenarioConfig(seed=7))
    assert time.perf_counter() - start < 1.0
    b = simulate(ScenarioConfig(seed=7))
    c = simulate(ScenarioConfig(seed=8))
    assert np.array_equal(a.controls, b.controls)
    assert np.array_equal(a.steps[10].ranges, b.steps[10].ranges)
    # The seed draws only the noises: the map and the true run are shared (Monte Carlo setting).
    assert np.array_equal(a.landmarks, c.landmarks)
    assert np.array_equal(a.true_poses, c.true_poses)
    assert not np.array_equal(a.controls, c.controls)


def test_route_is_a_closed_loop_driven_several_times(scenario):
    speed = np.hypot(*np.diff(scenario.true_poses[:, :2], axis=0).T) / 0.2
    assert np.allclose(speed, 3.0, atol=1e-6)
    assert np.all(np.abs(scenario.true_controls[:, 1]) <= math.radians(30) + 1e-12)
    start = scenario.true_poses[0, :2]
    distance_to_start = np.hypot(*(scenario.true_poses[:, :2] - start).T)
    # Returns near the start at least twice (2-3 laps of the loop).
    returns = np.flatnonzero((distance_to_start[1:] < 5.0) & (distance_to_start[:-1] >= 5.0))
    assert len(returns) >= 2


def test_every_landmark_observed_many_times_in_range_and_in_front(scenario):
    counts = np.bincount(np.concatenate([s.true_ids for s in scenario.steps]), minlength=20)
    assert counts.min() >= 50
    for k, step in enumerate(scenario.steps, start=1):
        clean = predict_observation(scenario.true_poses[k][None, :], scenario.landmarks[step.true_ids])
        assert np.all(clean[:, 0] <= 30.0)
        assert np.all(np.abs(clean[:, 1]) <= math.pi / 2)


def test_control_noise_statistics(scenario):
    err = scenario.controls - scenario.true_controls
    sigma = np.array([0.5, math.pi / 60])
    # Zero mean: within 4 standard errors sigma / sqrt(T).
    assert np.all(np.abs(err.mean(axis=0)) < 4 * sigma / math.sqrt(len(err)))
    assert err[:, 0].std() == pytest.approx(0.5, rel=0.1)
    assert err[:, 1].std() == pytest.approx(math.pi / 60, rel=0.1)


def test_observation_noise_statistics(scenario):
    res = _residuals(scenario)
    R = noise_covariance(slam_config_for(scenario).noise, np.zeros(()))
    assert len(res) > 2000
    assert np.abs(res.mean(axis=0) / np.sqrt(np.diag(R))).max() < 0.1
    cov = np.cov(res.T)
    assert np.allclose(np.diag(cov), np.diag(R), rtol=0.15)
    assert cov[0, 1] == pytest.approx(R[0, 1], abs=0.004)


def test_outliers_are_drawn_from_the_inflated_noise():
    s = simulate(ScenarioConfig(n_steps=1500, outlier_probability=0.2, seed=1))
    flags = np.concatenate([st.outlier for st in s.steps])
    assert flags.mean() == pytest.approx(0.2, abs=0.03)
    res = _residuals(s)
    ratio = res[flags].var(axis=0) / res[~flags].var(axis=0)
    assert np.all((ratio > 15) & (ratio < 40))           # 25 in expectation
    cfg = slam_config_for(s)
    assert cfg.noise.model == "mixture"
    assert cfg.noise.mixture_weights == pytest.approx((0.8, 0.2))
    assert cfg.noise.mixture_scales == pytest.approx((1.0, 25.0))


def test_unknown_ids_hide_identity_but_keep_truth():
    s = simulate(ScenarioConfig(n_steps=100, known_ids=False))
    for step in s.steps:
        assert np.all(step.ids == -1)
        assert np.all(step.true_ids >= 0)
        obs = step.observations()
        assert np.all(obs.ids == -1) and len(obs) == len(step.ranges)


def test_slam_config_matches_the_simulator(scenario):
    cfg = slam_config_for(scenario, num_particles=50, seed=4)
    assert cfg.motion.model == "bicycle" and cfg.motion.wheelbase == 4.0
    assert cfg.motion.sigma_speed == 0.5 and cfg.motion.sigma_steering == pytest.approx(math.pi / 60)
    assert cfg.motion.noise_reference_period == pytest.approx(0.2)
    assert cfg.sensor.max_range == 30.0
    assert (cfg.noise.sigma_range, cfg.noise.rho) == (0.5, 0.01)
    assert cfg.filter.num_particles == 50 and cfg.filter.seed == 4


def test_helpers():
    truth = np.array([[0.0, 0.0], [3.0, 4.0]])
    assert landmark_rmse(np.array([1, 0]), np.array([[3.0, 5.0], [0.0, 1.0]]), truth) == pytest.approx(1.0)

    class Recorder:
        def __init__(self):
            self.calls = []

        def add_control(self, stamp, u):
            self.calls.append(("u", stamp))

        def add_observations(self, stamp, obs):
            self.calls.append(("y", stamp))
            return len(obs)

    s = simulate(ScenarioConfig(n_steps=3))
    rec = Recorder()
    for step in s.steps:
        feed(rec, step)
    assert rec.calls == [("u", 0.0), ("y", 0.2), ("u", 0.2), ("y", pytest.approx(0.4)),
                         ("u", pytest.approx(0.4)), ("y", pytest.approx(0.6))]


def test_laps_repeat_the_same_closed_path_with_fresh_noise():
    s = simulate(ScenarioConfig(laps=3, seed=2))
    ends = s.lap_ends
    lap = int(ends[0])
    assert list(ends) == [lap, 2 * lap, 3 * lap] and s.n_steps == s.config.n_steps == 3 * lap
    # The same true path every lap (the controller's periodic path), closed on itself.
    np.testing.assert_allclose(s.true_poses[lap:2 * lap + 1], s.true_poses[:lap + 1], atol=1e-6)
    np.testing.assert_allclose(s.true_poses[-1], s.true_poses[0], atol=1e-6)
    np.testing.assert_allclose(s.true_controls[2 * lap:], s.true_controls[:lap], atol=1e-6)
    # Fresh noise each lap: the noise of two laps is uncorrelated.
    noise = s.controls - s.true_controls
    first, second = noise[:lap, 0], noise[lap:2 * lap, 0]
    assert abs(np.corrcoef(first, second)[0, 1]) < 0.15
    assert np.std(noise[:, 0]) == pytest.approx(0.5, rel=0.1)


def test_a_short_laps_run_is_the_prefix_of_a_longer_one():
    short, long = simulate(ScenarioConfig(laps=1, seed=4)), simulate(ScenarioConfig(laps=3, seed=4))
    T = short.n_steps
    assert long.lap_ends[0] == T
    assert np.array_equal(short.true_poses, long.true_poses[:T + 1])
    assert np.array_equal(short.controls, long.controls[:T])
    for a, b in zip(short.steps, long.steps[:T]):
        assert np.array_equal(a.ranges, b.ranges) and np.array_equal(a.bearings, b.bearings)
    # The seed run (laps = 0) is unchanged: n_steps steps from waypoint 0, laps counted.
    seed_run = simulate(ScenarioConfig(seed=4))
    assert seed_run.n_steps == 1500 and np.array_equal(seed_run.true_poses[0], [0.0, 0.0, seed_run.true_poses[0, 2]])
    assert len(seed_run.lap_ends) == 2
