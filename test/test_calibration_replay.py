"""The calibration replay (filter/warmup.py, ``noise_learning.replay_on_calibration``): once a
learned motion gain comes into use, the inputs so far are filtered again from the start with
the gains known, once; the warm-up replay still comes when every learned value is in use.

The simulated vehicle steers 0.7 times the commanded angle (as in test_motion_gains.py)."""
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.em.noise.learner import NoiseLearner
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for

STEERING_GAIN = 0.7


def _scenario(n_steps=400):
    return simulate(ScenarioConfig(seed=3, n_steps=n_steps))


def _config(scenario, warmup_observations, replay_on_calibration=True, noise_factor=1.0):
    """Gains and the observation noise learned, the noise started at ``noise_factor`` x its truth;
    the learned noise in use after ``warmup_observations`` (10**9: never, so no warm-up replay)."""
    config = slam_config_for(scenario, num_particles=30, seed=0)
    noise = replace(config.noise, sigma_range=noise_factor * config.noise.sigma_range,
                    sigma_bearing=noise_factor * config.noise.sigma_bearing)
    return replace_section(config, noise=noise, noise_learning=NoiseLearningConfig(
        enabled=True, learn=("range", "bearing", "motion_gains"), warmup_observations=warmup_observations,
        replay_on_calibration=replay_on_calibration))


def _feed(slam, step):
    slam.add_control(step.control_stamp, step.control / np.array([1.0, STEERING_GAIN]))
    return slam.add_observations(step.stamp, step.observations())


def _run(scenario, config, sliced=False):
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    slam.replay_in_slices = sliced
    states, catching_up = [], []
    for step in scenario.steps:
        _feed(slam, step)
        catching_up.append(slam.advance_replay(16) if sliced else False)
        learned = slam.learned_noise()
        states.append((learned["calibration_replayed"], learned["warmup_replayed"]))
    return slam, states, catching_up


def test_a_gain_in_use_has_the_inputs_so_far_filtered_again_from_the_start_with_it(monkeypatch):
    """The first pass steers at the configured gain 1.0 until the learned 0.7 comes into use; then
    a new estimator filters every input so far from the first one at the known gains, holding the
    values in use, and takes over. Once; the inputs stay kept for the warm-up replay; drops are
    not counted twice."""
    seen = []
    update = NoiseLearner.update

    def recording(self, *args, **kwargs):
        seen.append((self.holding, self.gains_in_use.copy()))
        update(self, *args, **kwargs)
    monkeypatch.setattr(NoiseLearner, "update", recording)
    scenario = _scenario()
    slam, states, _ = _run(scenario, _config(scenario, 10 ** 9))
    replayed_at = states.index((True, False))
    assert states[replayed_at:] == [(True, False)] * (len(states) - replayed_at)       # once, no warm-up replay
    assert slam._warmup_log is not None and len(slam._warmup_log) == 2 * len(scenario.steps)
    assert seen[0][1][1] == 1.0                                                   # the first pass: configured
    held = [k for k, (holding, _) in enumerate(seen) if holding]
    # The replay: every filter step up to the one that made it due, again, at the known gains.
    assert held == list(range(held[0], held[0] + replayed_at + 1)) and held[0] == replayed_at + 1
    known = seen[held[0]][1]
    assert known[1] == pytest.approx(STEERING_GAIN, abs=0.1)
    assert all(np.array_equal(seen[k][1], known) for k in held)
    plain, plain_states, _ = _run(scenario, _config(scenario, 10 ** 9, replay_on_calibration=False))
    assert plain_states[-1] == (False, False) and slam.drops == plain.drops


def test_the_warmup_replay_still_comes_once_every_learned_value_is_in_use():
    """Started from 3x the observation noise, which the learned values differ from (at the truth
    the warm-up replay is needless: start_difference.py)."""
    scenario = _scenario(1000)
    slam, states, _ = _run(scenario, _config(scenario, 1500, noise_factor=3.0))
    calibrated, warmed = states.index((True, False)), states.index((True, True))
    assert calibrated < warmed and states[-1] == (True, True)
    assert slam._warmup_log is None                               # nothing left to replay
    assert slam.learned_noise()["motion_gains"][1] == pytest.approx(STEERING_GAIN, rel=0.05)


def test_a_calibration_replay_in_slices_ends_where_the_replay_at_once_does():
    scenario = _scenario()
    config = _config(scenario, 10 ** 9)
    at_once, _, _ = _run(scenario, config)
    sliced, states, catching_up = _run(scenario, config, sliced=True)
    assert any(catching_up) and not catching_up[-1] and states[-1] == (True, False)
    for name in ("ids", "positions", "covariances", "n_obs"):
        assert np.array_equal(getattr(at_once.landmarks(), name), getattr(sliced.landmarks(), name)), name
    assert np.array_equal(at_once.particles()[0], sliced.particles()[0])
    assert at_once.learned_noise() == sliced.learned_noise() and at_once.drops == sliced.drops
