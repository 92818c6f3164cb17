"""Replays as the inputs grow (filter/warmup.py, ``noise_learning.replay_growth``): after the
warm-up replay the inputs stay kept and are filtered again from the start each time they have
grown g-fold since the last replay started, under the values learned from all of them."""
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.filter.warmup import WarmupReplay
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for


def _config(scenario, growth):
    """The observation noise started 3x its truth, which the learned values then differ from (the
    warm-up replay is needless at the truth: start_difference.py)."""
    config = slam_config_for(scenario, num_particles=30, seed=0)
    noise = replace(config.noise, sigma_range=3.0 * config.noise.sigma_range,
                    sigma_bearing=3.0 * config.noise.sigma_bearing)
    return replace_section(config, noise=noise, noise_learning=NoiseLearningConfig(
        enabled=True, learn=("range", "bearing"), warmup_observations=100, replay_growth=growth))


def _run(scenario, config, sliced=False, monkeypatch=None):
    starts = []
    if monkeypatch is not None:
        restarted = WarmupReplay._restarted

        def counting(self, estimator):
            starts.append(len(self.inputs))
            return restarted(self, estimator)
        monkeypatch.setattr(WarmupReplay, "_restarted", counting)
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    slam.replay_in_slices = sliced
    for step in scenario.steps:
        slam.add_control(step.control_stamp, step.control)
        slam.add_observations(step.stamp, step.observations())
        if sliced:
            slam.advance_replay(16)
    return slam, starts


@pytest.fixture(scope="module")
def scenario():
    return simulate(ScenarioConfig(seed=3, n_steps=500))


def test_each_replay_comes_once_the_inputs_have_grown_by_the_factor(scenario, monkeypatch):
    """The warm-up replay, then one at twice its inputs and one at twice those (two inputs, a
    control and a scan, per step of 1000 in all); the inputs stay kept for the next."""
    slam, starts = _run(scenario, _config(scenario, 2.0), monkeypatch=monkeypatch)
    assert len(starts) == 3 and starts[-1] * 2 > 2 * len(scenario.steps)   # 140, 280, 560 of 1000
    for before, after in zip(starts, starts[1:]):
        assert 2 * before <= after <= 2 * before + 1           # due at the first input past 2x
    assert slam._warmup_log is not None and len(slam._warmup_log) == 2 * len(scenario.steps)
    assert slam.learned_noise()["warmup_replayed"] and slam.learned_noise()["replays"] == 3


def test_without_growth_the_warmup_replay_comes_once(scenario, monkeypatch):
    slam, starts = _run(scenario, _config(scenario, 0.0), monkeypatch=monkeypatch)
    assert len(starts) == 1 and slam._warmup_log is None and slam.learned_noise()["replays"] == 1


def test_replays_in_slices_end_where_the_replays_at_once_do(scenario, monkeypatch):
    config = _config(scenario, 1.5)
    at_once, starts = _run(scenario, config, monkeypatch=monkeypatch)
    assert len(starts) >= 3                                    # the warm-up replay and two as they grow
    sliced, _ = _run(scenario, config, sliced=True)
    for name in ("ids", "positions", "covariances", "n_obs"):
        assert np.array_equal(getattr(at_once.landmarks(), name), getattr(sliced.landmarks(), name)), name
    assert at_once.learned_noise() == sliced.learned_noise() and at_once.drops == sliced.drops


@pytest.mark.parametrize("growth", [0.5, 1.0])
def test_a_growth_factor_not_above_one_is_refused(growth):
    with pytest.raises(ValueError, match="replay_growth"):
        NoiseLearningConfig(enabled=True, replay_growth=growth).validate()
