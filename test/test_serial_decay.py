"""A serial correlation that decays with the viewpoint's change (noise.serial_length): each
observation's c = c0 exp(-v / l), its R weighed by it, and (c0, l) learned from binned pairs;
each piece against an independent computation."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.core.em.noise.serial_correlation import DECAY_LENGTHS, ViewpointPairs, decay_fit
from online_em_slam.core.filter.serial_errors import LastInnovations, ar1_log_likelihood
from online_em_slam.core.mapping.last_sighting import LastSightings
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.models.observation import (information_noise, noise_covariance, observation_correlation,
                                                    serially_weighed, viewpoint_change)
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

NOISE = ObservationNoiseConfig(sigma_range=0.2, sigma_bearing=0.03, rho=0.002, range_growth=0.01,
                               serial_correlation=(0.8, 0.5), serial_length=(0.4, 0.25), serial_turn_length=1.5)


def test_one_correlation_for_all_weighs_as_information_noise():
    """With the same c for every observation the per-observation weighing is information_noise's R."""
    ranges = np.array([0.5, 2.0, 7.0])
    c = np.tile(NOISE.serial_correlation, (3, 1))
    np.testing.assert_allclose(serially_weighed(noise_covariance(NOISE, ranges), c),
                               noise_covariance(information_noise(NOISE), ranges), rtol=1e-12)


def test_the_correlation_decays_by_e_over_its_length_and_a_first_sighting_has_none():
    v = np.array([0.0, 0.4, 0.25, np.inf])
    c = observation_correlation(NOISE, v)
    np.testing.assert_allclose(c[0], [0.8, 0.5])
    assert c[1, 0] == pytest.approx(0.8 / math.e) and c[2, 1] == pytest.approx(0.5 / math.e)
    np.testing.assert_array_equal(c[3], [0.0, 0.0])
    constant = observation_correlation(replace(NOISE, serial_length=(0.0, 0.0)), v)    # no decay: c0 for all
    np.testing.assert_array_equal(constant, np.tile([0.8, 0.5], (4, 1)))


def test_the_viewpoint_change_is_travel_plus_the_turn_at_its_length():
    rng = np.random.default_rng(0)
    previous, pose = rng.normal(size=(5, 3)) * 3.0, rng.normal(size=3) * 3.0
    previous[2] = np.nan
    got = viewpoint_change(previous, pose, 1.5)
    for k in range(5):
        turn = abs(math.remainder(pose[2] - previous[k, 2], 2 * math.pi)) if k != 2 else math.nan
        expected = math.inf if k == 2 else math.dist(pose[:2], previous[k, :2]) + 1.5 * turn
        assert got[k] == pytest.approx(expected, rel=1e-12)


def test_last_sightings_recall_what_a_dictionary_would():
    rng = np.random.default_rng(1)
    table, reference = LastSightings(2), {}
    for _ in range(200):
        ids = rng.integers(0, 30, rng.integers(0, 6))
        values = rng.normal(size=(ids.size, 2))
        query = rng.integers(0, 35, 8)
        expected = np.array([reference.get(int(i), (np.nan, np.nan)) for i in query])
        np.testing.assert_array_equal(table.recall(query), expected.reshape(-1, 2))
        table.record(ids, values)
        for i, row in zip(ids.tolist(), values):
            reference[i] = tuple(row)                    # an id twice: its last row
    assert np.all(np.diff(table.ids) > 0) and table.ids.size == len(reference)


def test_last_sightings_take_any_integer_ids_and_keep_an_ids_last_row():
    table = LastSightings(1)
    table.record(np.array([2 ** 40, -3, 2 ** 40]), np.array([[1.0], [2.0], [3.0]]))
    np.testing.assert_array_equal(table.recall(np.array([-3, 2 ** 40, 7])), [[2.0], [3.0], [np.nan]])
    table.record(np.arange(100), np.arange(100.0)[:, None])          # grows past its first rows
    np.testing.assert_array_equal(table.recall(np.array([99, -3])), [[99.0], [2.0]])


def test_the_fit_recovers_an_exact_decay():
    v = np.array([0.005, 0.015, 0.03, 0.07, 0.15, 0.3, 0.6, 1.2, 2.5])
    length = (DECAY_LENGTHS[30], DECAY_LENGTHS[20])                       # lengths on the fit's grid
    c = np.stack([0.9 * np.exp(-v / length[0]), 0.6 * np.exp(-v / length[1])], axis=1)
    moments = np.hstack([c, np.ones((v.size, 4))])                        # unit variances: c itself
    c0, fitted = decay_fit(np.ones(v.size), v, moments, 0.95)
    assert c0 == pytest.approx((0.9, 0.6), abs=1e-9) and fitted == pytest.approx(length, rel=1e-12)


def test_binned_pairs_of_simulated_sightings_give_the_decay():
    """Errors of 40 landmarks AR(1) from sighting to sighting with c(v) = 0.9 exp(-v / 0.3) (range)
    and 0.6 exp(-v / 0.1) (bearing), v the robot's random travel between scans: the fit's c0
    within 0.05 and l within 25 %."""
    rng = np.random.default_rng(3)
    pairs, ids = ViewpointPairs(turn_length=1.0, alpha=1.0), np.arange(40)
    c0, length = np.array([0.9, 0.6]), np.array([0.3, 0.1])
    z, pose = rng.standard_normal((40, 2)), np.zeros(3)
    for _ in range(1500):
        pairs.blend(ids, z, np.zeros((40, 2)), pose)
        step = rng.choice([0.003, 0.01, 0.03, 0.06, 0.12, 0.25, 0.5, 1.0])
        pose = pose + np.array([step, 0.0, 0.0])
        c = c0 * np.exp(-step / length)
        z = c * z + np.sqrt(1.0 - c * c) * rng.standard_normal((40, 2))
    fitted_c0, fitted_length = pairs.fit(0.95)
    assert fitted_c0 == pytest.approx(c0, abs=0.05)
    assert fitted_length == pytest.approx(length, rel=0.25)


def test_each_observations_own_constant_correlation_is_the_one_correlations_ar1():
    """ar1 with each observation's c equal to the one c, unmatched ones under the marginal R: the
    same log-likelihood as the one-c path."""
    rng = np.random.default_rng(4)
    R = noise_covariance(NOISE, np.array([1.0, 2.0, 3.0]))
    last = LastInnovations()
    last.store(4, np.array([1, 2]), rng.normal(0.0, 0.1, (5, 2, 2)))
    nu, ancestors = rng.normal(0.0, 0.1, (5, 3, 2)), rng.integers(0, 5, 5)
    ids, weighting = np.array([2, 9, 1]), np.ones(3, dtype=bool)
    one = ar1_log_likelihood(last, 5, ids, nu, R, ancestors, NOISE, weighting)
    own = ar1_log_likelihood(last, 5, ids, nu, R, ancestors, NOISE, weighting,
                             np.tile(NOISE.serial_correlation, (3, 1)), R)
    np.testing.assert_allclose(own, one, rtol=1e-12)


def test_the_batch_measures_viewpoints_as_a_loop_over_sightings_would():
    from online_em_slam.offline.batch import InputsProblem, viewpoint_changes
    from online_em_slam.baselines.gtsam_batch import compose
    from collections import Counter

    rng = np.random.default_rng(5)
    T, P = 30, 80
    increments = rng.normal(0.0, 0.2, (T - 1, 3))
    problem = InputsProblem(np.arange(T, dtype=float), increments, np.zeros((T - 1, 3, 3)),
                            np.sort(rng.integers(0, T, P)), rng.integers(0, 6, P), np.zeros((P, 2)),
                            np.zeros((P, 2, 2)), Counter(), chain_starts=(0, 15))
    config = slam_config_for(simulate(ScenarioConfig(seed=0, n_steps=5)))
    config = replace(config, noise=replace(config.noise, serial_turn_length=0.7))
    poses = [np.zeros(3)]
    for k in range(1, T):
        poses.append(np.zeros(3) if k == 15 else compose(poses[-1], increments[k - 1]))
    last, expected = {}, []
    for landmark, k in zip(problem.obs_id.tolist(), problem.obs_pose.tolist()):
        chain = int(k >= 15)
        before = last.get((landmark, chain))
        if before is None:
            expected.append(math.inf)
        else:
            d = poses[k] - poses[before]
            expected.append(math.hypot(d[0], d[1]) + 0.7 * abs(float(wrap_angle(d[2]))))
        last[(landmark, chain)] = k
    np.testing.assert_allclose(viewpoint_changes(problem, config), expected, rtol=1e-12)


def test_the_filter_weighs_each_observation_by_its_own_correlation_and_learns_the_decay():
    """On the simulator with serial_length learned: the statistics take every observation (the
    learner finds R as the filter made it), the decay is learned, the map stays finite."""
    scenario = simulate(ScenarioConfig(seed=0, n_steps=300))
    config = slam_config_for(scenario, num_particles=30)
    learning = replace(config.noise_learning, enabled=True,
                       learn=("range", "bearing", "serial_correlation", "serial_length"))
    config = replace(config, noise_learning=learning,
                     noise=replace(config.noise, serial_correlation=(0.5, 0.5), serial_length=(0.5, 0.5)))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    seen = []
    update = slam._noise.update

    def spy(data, n_obs, ids=None):
        if data.rows.size:
            seen.append((data.serial, slam._noise._configured_R(data, slam._noise.weighed_noise())[0]))
        return update(data, n_obs, ids)

    slam._noise.update = spy
    for step in scenario.steps:
        feed(slam, step)
    assert all(serial is not None and configured.all() for serial, configured in seen)
    assert np.isfinite(slam.landmarks().positions).all()
    assert all(length > 0.0 for length in slam.learned_noise()["serial_length"])
    assert slam._noise.serial.pairs.counts.sum() > 0                         # pairs were binned
    assert tuple(slam._noise.estimate.serial_length) != (0.5, 0.5)          # and the decay fitted


def test_a_saved_map_keeps_the_decay_and_refuses_a_wrong_one(tmp_path):
    from online_em_slam.core.mapping import mapfile

    scenario = simulate(ScenarioConfig(seed=0, n_steps=120))
    config = slam_config_for(scenario, num_particles=20)
    config = replace(config, noise_learning=replace(config.noise_learning, enabled=True,
                                                    learn=("range", "serial_correlation", "serial_length")),
                     noise=replace(config.noise, serial_correlation=(0.5, 0.4), serial_length=(0.3, 0.2)))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    path = str(tmp_path / "map.npz")
    slam.save_map(path)
    fresh = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    fresh.load_map(path)
    assert fresh.learned_noise_parameters()["noise.serial_length"] == slam.learned_noise_parameters()[
        "noise.serial_length"]
    arrays = dict(np.load(path))
    arrays["noise_serial_length"] = np.array([0.3, -1.0])
    with pytest.raises(mapfile.MapFileError, match="noise_serial_length"):
        mapfile.check_map(arrays)


def _replays(monkeypatch, known_after: int | None) -> tuple[list[int], OnlineEMSlam]:
    """The steps at which the warm-up replay started, with the serial decay known from filter
    step ``known_after`` on (None: from the start)."""
    from online_em_slam.core.em.noise.learner import NoiseLearner
    from online_em_slam.core.filter.warmup import WarmupReplay

    scenario = simulate(ScenarioConfig(seed=1, n_steps=400))
    config = slam_config_for(scenario, num_particles=20)
    config = replace(config, noise_learning=replace(config.noise_learning, enabled=True, warmup_observations=50,
                                                    learn=("range", "bearing", "serial_correlation", "serial_length")))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    starts, replay = [], WarmupReplay.replay
    monkeypatch.setattr(NoiseLearner, "serial_known", property(
        lambda self: known_after is None or slam._step >= known_after))
    monkeypatch.setattr(WarmupReplay, "replay", lambda self, estimator, *a: (starts.append(estimator._step),
                                                                             replay(self, estimator, *a)))
    for step in scenario.steps:
        feed(slam, step)
    return starts, slam


def test_the_warmup_is_filtered_again_once_the_serial_decay_is_known(monkeypatch):
    """The decay unknown when the warm-up replay starts: one more replay once it is known, then
    no inputs are kept; known from the start: the one replay."""
    once, slam = _replays(monkeypatch, None)
    assert len(once) == 1 and slam._warmup.inputs is None
    twice, slam = _replays(monkeypatch, once[0] + 60)
    assert len(twice) == 2 and twice[0] == once[0] and twice[1] >= once[0] + 60
    assert slam._warmup.inputs is None and slam.learned_noise()["warmup_replayed"]


def test_the_quasi_differences_noise_stays_a_covariance():
    """c = (0.95, 0) with a range-bearing correlation of 0.9: R - C R C is not positive definite;
    the likelihood's Q keeps R - C R C's diagonal and a valid cross term, and the log-likelihood
    is finite."""
    from online_em_slam.core.filter.serial_errors import innovation_noise

    R = np.array([[[0.04, 0.9 * 0.2 * 0.03], [0.9 * 0.2 * 0.03, 0.0009]]])
    c = np.array([[0.95, 0.0]])
    Q = innovation_noise(R, c, np.ones(1, dtype=bool))
    assert np.all(np.linalg.eigvalsh(Q) > 0.0)
    np.testing.assert_allclose(np.diagonal(Q, axis1=-2, axis2=-1), [[0.04 * (1 - 0.95 ** 2), 0.0009]])
    last = LastInnovations()
    last.store(0, np.array([3]), np.full((4, 1, 2), 0.1))
    noise = replace(NOISE, model="student_t", rho=0.9 * 0.2 * 0.03, serial_correlation=(0.95, 0.0))
    loglik = ar1_log_likelihood(last, 1, np.array([3]), np.full((4, 1, 2), -0.1), R, np.arange(4), noise,
                                np.ones(1, dtype=bool))
    assert np.isfinite(loglik).all()
