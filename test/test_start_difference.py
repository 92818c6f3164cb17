"""Whether the learned values differ from those the warm-up began under (core/em/noise/
start_difference.py): the standard errors against simulated averages, the chi-square test, and
the warm-up replay left out where the data cannot tell the values apart."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import digamma
from scipy.stats import chi2

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.em.noise.averages import StochasticAverage, batch_step_size
from online_em_slam.core.em.noise.serial_correlation import serial_correlation
from online_em_slam.core.em.noise.start_difference import (chi_square_quantile, differs, dof_information,
                                                          observation_scores)
from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

ALPHA, SCANS, PER_SCAN, RUNS = 0.7, 300, 3, 2000


def averaged(samples: np.ndarray) -> tuple[np.ndarray, float]:
    """The learner's average (StochasticAverage, one scan's mean per blend) of ``samples``
    (runs, scans, per scan, k) for every run at once, and its squared weights q."""
    value, count, q = None, 0, 0.0
    for scan in np.moveaxis(samples, 1, 0):
        sample = scan.mean(axis=1)
        gamma = 1.0 if value is None else batch_step_size(count, PER_SCAN, ALPHA)
        value = sample if value is None else value + gamma * (sample - value)
        q = (1.0 - gamma) ** 2 * q + gamma ** 2 / PER_SCAN
        count += PER_SCAN
    reference = StochasticAverage(ALPHA)
    for scan in samples[0]:
        reference.blend(scan.mean(axis=0), PER_SCAN)
    assert reference.value == pytest.approx(value[0], rel=1e-12) and reference.squared_weights == pytest.approx(q)
    return value, q


def test_the_chi_square_quantile_is_scipys():
    for dof in (1, 2, 5, 9):
        for p in (0.5, 0.95, 0.999):
            assert chi_square_quantile(p, dof) == pytest.approx(chi2.ppf(p, dof), rel=1e-10)


@pytest.mark.parametrize("dof", [3.0, 8.0])
def test_the_dof_information_is_the_scores_second_moment(dof):
    """Monte Carlo: the mean squared derivative of the bivariate t's log density in its dof."""
    rng = np.random.default_rng(1)
    tau = rng.gamma(dof / 2, 2 / dof, 400_000)
    d2 = (rng.standard_normal((tau.size, 2)) ** 2).sum(axis=1) / tau
    score = (0.5 * digamma((dof + 2) / 2) - 0.5 * digamma(dof / 2) - 1 / dof - 0.5 * np.log1p(d2 / dof)
             + (dof + 2) / 2 * d2 / dof ** 2 / (1 + d2 / dof))
    assert np.mean(score ** 2) == pytest.approx(dof_information(dof), rel=0.05)


def test_the_observation_standard_errors_are_those_of_simulated_averages():
    """sigma from averaged squared errors, rho from averaged products: their spread over runs is
    the standard error the test divides by (start values true, Gaussian errors)."""
    rng = np.random.default_rng(2)
    sr, sb, rho = 0.5, 0.05, 0.01
    cov = np.array([[sr * sr, rho], [rho, sb * sb]])
    e = rng.multivariate_normal(np.zeros(2), cov, (RUNS, SCANS, PER_SCAN))
    value, q = averaged(np.stack([e[..., 0] ** 2, e[..., 1] ** 2, e[..., 0] * e[..., 1]], axis=-1))
    start = ObservationNoiseConfig(sigma_range=sr, sigma_bearing=sb, rho=rho)
    scores = np.array([observation_scores({"range", "bearing", "correlation"},
                                          replace(start, sigma_range=float(np.sqrt(v[0])),
                                                  sigma_bearing=float(np.sqrt(v[1])), rho=float(v[2])), start, q, 0.0)
                       for v in value])
    np.testing.assert_allclose(scores.std(axis=0), 1.0, atol=0.08)
    np.testing.assert_allclose(scores.mean(axis=0), 0.0, atol=0.1)


@pytest.mark.parametrize("c0", [0.0, 0.6])
def test_the_serial_correlations_standard_error_is_that_of_simulated_pairs(c0):
    rng = np.random.default_rng(3)
    before = rng.standard_normal((RUNS, SCANS, PER_SCAN))
    now = c0 * before + np.sqrt(1 - c0 * c0) * rng.standard_normal(before.shape)
    value, q = averaged(np.stack([before * now, before * now, before ** 2, before ** 2, now ** 2, now ** 2], axis=-1))
    c = np.array([serial_correlation(v, 0.99)[0] for v in value])
    start = ObservationNoiseConfig(serial_correlation=(c0, c0))
    scores = [observation_scores({"serial_correlation"}, replace(start, serial_correlation=(cj, c0)), start, 1.0, q)[0]
              for cj in c]
    spread = np.std(scores) if c0 > 0 else np.sqrt(np.mean(np.square(scores)) * 2)   # c >= 0: half a normal
    assert spread == pytest.approx(1.0, abs=0.1)


def test_the_test_replays_unless_the_scores_stay_within_the_quantile():
    assert differs(None) and differs([np.nan]) and differs([np.inf])
    assert not differs([]) and not differs([1.9]) and differs([2.0])      # chi-square(1) at 0.95: 3.84
    assert not differs([1.5, 1.5]) and differs([2.0, 2.0])                # chi-square(2) at 0.95: 5.99


def _run(seed: int, factor: float, replay: bool = True) -> OnlineEMSlam:
    scenario = simulate(ScenarioConfig(seed=seed, n_steps=800))
    config = slam_config_for(scenario, num_particles=30, seed=0)
    noise = replace(config.noise, sigma_range=factor * config.noise.sigma_range,
                    sigma_bearing=factor * config.noise.sigma_bearing)
    config = replace_section(config, noise=noise, noise_learning=NoiseLearningConfig(enabled=True,
                                                                                       replay_warmup=replay))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    return slam


def test_a_warmup_begun_at_the_learned_values_is_not_replayed():
    """Started at its truth, every learned value comes into use without the data telling it from
    the start: no replay, and the run is the one without the replay, bit for bit.  Started at 3x
    the observation noise, the same run replays."""
    skipped, plain = _run(1, 1.0), _run(1, 1.0, replay=False)
    learned = skipped.learned_noise()
    assert learned["warmup_replay_needless"] and not learned["warmup_replayed"] and learned["replays"] == 0
    assert learned["observation_noise_in_use"] and learned["motion_scale_in_use"]
    for name in ("ids", "positions", "covariances", "n_obs"):
        assert np.array_equal(getattr(skipped.landmarks(), name), getattr(plain.landmarks(), name)), name
    started_wrong = _run(1, 3.0).learned_noise()
    assert started_wrong["warmup_replayed"] and not started_wrong["warmup_replay_needless"]


def test_a_dof_without_information_cannot_be_told_apart():
    """At a dof so large that its information rounds away, a change says nothing: z = 0."""
    start = ObservationNoiseConfig(model="student_t", dof=1e300)
    assert observation_scores({"dof"}, replace(start, dof=5.0), start, 0.01, 0.0) == [0.0]
