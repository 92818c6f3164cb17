"""Student-t observation noise (issue 9: heavy-tailed detections such as Victoria Park's trees).

Each piece against an independent computation: the log-density against scipy's
multivariate t, the gates against the empirical quantiles of sampled t noise,
the degrees-of-freedom M-step against a batch EM on samples of known dof, and
the whole learner on a seeded simulation with t noise.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats
from scipy.special import digamma

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import AssociationConfig, NoiseLearningConfig, ObservationNoiseConfig, replace_section
from online_em_slam.core.em.noise.observation import student_t_dof
from online_em_slam.core.filter.association import Gates, chi_square_2_quantile
from online_em_slam.core.models.observation import (component_precision_weight, mahalanobis_2d, noise_loglik,
                                                    student_t_weight)
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

S = np.array([[0.09, 0.001], [0.001, 0.0004]])
T_NOISE = ObservationNoiseConfig(model="student_t", dof=4.0, sigma_range=0.3, sigma_bearing=0.02, rho=0.001)


def t_samples(rng, dof: float, n: int) -> np.ndarray:
    """Draws of t_dof(0, S): N(0, S / tau), tau ~ Gamma(dof/2, rate dof/2)."""
    tau = rng.gamma(0.5 * dof, 2.0 / dof, n)
    return rng.standard_normal((n, 2)) @ np.linalg.cholesky(S).T / np.sqrt(tau)[:, None]


def test_student_t_loglik_is_scipy_multivariate_t():
    nu = np.random.default_rng(0).normal(size=(50, 2)) * [0.5, 0.05]
    loglik, latent = noise_loglik(T_NOISE, nu, np.broadcast_to(S, (50, 2, 2)))
    assert loglik == pytest.approx(stats.multivariate_t(np.zeros(2), S, df=4.0).logpdf(nu), rel=1e-10)
    d2, _ = mahalanobis_2d(nu, S)
    assert latent[:, 0] == pytest.approx((4.0 + 2.0) / (4.0 + d2), rel=1e-12)
    assert component_precision_weight(T_NOISE, latent) == pytest.approx(latent[:, 0])


@pytest.mark.parametrize("dof", [3.0, 10.0])
def test_gates_are_the_quantiles_of_the_t_distance(dof):
    noise = replace(T_NOISE, dof=dof)
    gates = Gates.from_config(AssociationConfig(gate_probability=0.95, new_landmark_probability=0.99), noise)
    d2, _ = mahalanobis_2d(t_samples(np.random.default_rng(1), dof, 200_000), S)
    assert np.mean(d2 < gates.associate) == pytest.approx(0.95, abs=0.003)
    assert np.mean(d2 < gates.create) == pytest.approx(0.99, abs=0.001)
    gaussian = Gates.from_config(AssociationConfig(gate_probability=0.95, new_landmark_probability=0.99))
    assert gaussian.associate == pytest.approx(stats.chi2.ppf(0.95, 2)) and gaussian.dof is None


def test_chi_square_gates_in_closed_form_are_scipys_quantiles():
    for p in (1e-9, 0.5, 0.9, 0.95, 0.99, 0.999, 0.9999, 0.999999999):
        assert chi_square_2_quantile(p) == pytest.approx(stats.chi2.ppf(p, 2), rel=1e-15)


def test_the_t_cost_is_twice_the_negative_log_density_up_to_a_constant():
    gates = Gates.from_config(AssociationConfig(), T_NOISE)
    nu = np.array([[0.1, 0.01], [1.0, -0.03], [-2.0, 0.1]])
    d2, logdet = mahalanobis_2d(nu, S)
    loglik, _ = noise_loglik(T_NOISE, nu, np.broadcast_to(S, (3, 2, 2)))
    assert np.ptp(gates.cost(d2, logdet) + 2.0 * loglik) < 1e-9


@pytest.mark.parametrize("dof", [3.5, 8.0])
def test_the_dof_m_step_recovers_the_dof_by_batch_em(dof):
    """Batch EM on 40 000 draws: E-step statistic at the current dof, then the M-step root."""
    d2, _ = mahalanobis_2d(t_samples(np.random.default_rng(2), dof, 40_000), S)
    estimate = 30.0
    for _ in range(300):
        u = student_t_weight(d2, estimate)
        statistic = float(np.mean(_expected_log_tau(d2, estimate) - u))
        estimate = student_t_dof(statistic, 0.5, 1e4)
    assert estimate == pytest.approx(dof, rel=0.08)


def _expected_log_tau(d2: np.ndarray, dof: float) -> np.ndarray:
    """E[log tau | d2] of tau | nu ~ Gamma((dof + 2)/2, rate (dof + d2)/2), by scipy's digamma."""
    return digamma(0.5 * (dof + 2.0)) - np.log(0.5 * (dof + d2))


def test_the_dof_m_step_stays_within_its_limits():
    assert student_t_dof(-1.0 - 1e-12, 3.0, 100.0) == 100.0        # as light as a Gaussian: the ceiling
    assert student_t_dof(-5.0, 3.0, 100.0) == 3.0                   # heavier than the floor allows
    mid = student_t_dof(-1.2, 0.5, 1e4)
    assert 1.0 + math.log(mid / 2) - digamma(mid / 2) - 1.2 == pytest.approx(0.0, abs=1e-9)


# ----------------------------------------------------------------- the learner on t noise
TRUTH = dict(n_landmarks=40, sigma_range=0.3, sigma_bearing=0.02, rho=0.0, sigma_speed=0.3, sigma_steering=0.03)


@pytest.mark.parametrize("factor", [3.0, 1 / 3])
def test_heavy_tailed_noise_is_learned_by_the_student_t_model(factor):
    """t_4 noise; the estimator starts 3x off in every std, from dof 20: R within 10 %, dof near 4."""
    scenario = simulate(ScenarioConfig(seed=2, noise_dof=4.0, **TRUTH))
    truth = slam_config_for(scenario, num_particles=50)
    noise = replace(truth.noise, sigma_range=0.3 * factor, sigma_bearing=0.02 * factor, dof=20.0)
    motion = replace(truth.motion, sigma_speed=0.3 * factor, sigma_steering=0.03 * factor)
    slam = OnlineEMSlam(replace_section(truth, noise=noise, motion=motion,
                                        noise_learning=NoiseLearningConfig(enabled=True)),
                        initial_pose=scenario.initial_pose)
    for step in scenario.steps:
        feed(slam, step)
    learned = slam.learned_noise()
    assert learned["model"] == "student_t" and learned["observation_noise_in_use"]
    assert learned["sigma_range"] == pytest.approx(0.3, rel=0.10)
    assert learned["sigma_bearing"] == pytest.approx(0.02, rel=0.10)
    assert 3.0 <= learned["dof"] <= 5.5
    assert slam.learned_noise_parameters()["noise.dof"] == learned["dof"]


def test_the_learned_dof_travels_with_the_map_file_and_a_bad_one_is_refused(tmp_path):
    from online_em_slam.core.mapping import mapfile

    scenario = simulate(ScenarioConfig(seed=1, n_steps=300, noise_dof=4.0, **TRUTH))
    truth = slam_config_for(scenario, num_particles=20)
    config = replace_section(truth, noise=replace(truth.noise, dof=20.0),
                             noise_learning=NoiseLearningConfig(enabled=True, warmup_observations=50))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    for step in scenario.steps:
        feed(slam, step)
    path = str(tmp_path / "map.npz")
    slam.save_map(path)
    in_use = slam.learned_noise_parameters()["noise.dof"]
    assert in_use != 20.0 and float(np.load(path)["noise_dof"]) == in_use
    fresh = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    fresh.load_map(path)
    assert fresh.learned_noise_parameters()["noise.dof"] == in_use
    for bad in (np.array(-1.0), np.array(np.nan), np.array([4.0, 5.0])):
        with pytest.raises(mapfile.MapFileError, match="noise_dof"):
            mapfile.check_map({**dict(np.load(path)), "noise_dof": bad})
