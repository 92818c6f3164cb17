"""The unicycle's turn per metre driven (motion.turn_per_meter): a differential drive whose wheels
differ a little turns while commanded straight; learned with the gains' statistic (motion_drift)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core import Observations, OnlineEMSlam, SlamConfig
from online_em_slam.core.config import MotionConfig, NoiseLearningConfig, SensorConfig
from online_em_slam.core.models.motion import DRIFT, calibrated, integrate_segments

KAPPA = -0.05                       # rad/m: 2.9 deg per metre, the order of MRCLAM's robots (-0.004 to -0.038)


def _unicycle(**values) -> MotionConfig:
    return MotionConfig(model="unicycle", max_prediction_interval=10.0, **values)


def test_the_yaw_rate_gains_the_turn_per_metre_of_the_speed_delivered():
    config = _unicycle(translation_gain=0.9, rotation_gain=0.8, turn_per_meter=KAPPA)
    controls = np.array([[0.5, 0.2], [0.0, -0.3], [1.0, 0.0]])
    expected = np.column_stack([0.9 * controls[:, 0], 0.8 * controls[:, 1] + KAPPA * 0.9 * controls[:, 0]])
    np.testing.assert_allclose(calibrated(config, controls), expected, rtol=1e-15)
    uncalibrated = _unicycle()
    assert calibrated(uncalibrated, controls) is controls              # nothing to calibrate: no copy
    np.testing.assert_array_equal(calibrated(_unicycle(turn_per_meter=0.0, rotation_gain=0.8), controls),
                                  controls * [1.0, 0.8])


def test_a_turn_per_metre_is_refused_where_the_input_is_not_a_yaw_rate():
    with pytest.raises(ValueError, match="turn_per_meter is a calibration of the unicycle"):
        MotionConfig(model="bicycle", turn_per_meter=0.01).validate()
    config = replace(SlamConfig(), noise_learning=NoiseLearningConfig(enabled=True, learn=("motion_drift",)))
    with pytest.raises(ValueError, match="motion_drift .* is learned for the unicycle model, not the bicycle"):
        config.validate()
    replace(config, motion=_unicycle()).validate()


def test_the_filters_sensitivity_to_the_turn_per_metre_is_the_finite_difference_of_the_track():
    """The sensitivity the filter carries from one filter step to the next (d pose / d turn_per_meter,
    the column (G) reads) against (end(k + h) - end(k - h)) / 2h of the same controls integrated afresh."""
    config = replace(SlamConfig(), motion=_unicycle(turn_per_meter=KAPPA),
                     noise_learning=NoiseLearningConfig(enabled=True, learn=("motion_gains", "motion_drift")))
    slam = OnlineEMSlam(config, initial_pose=(1.0, 2.0, 0.3), stamp=0.0)
    slam.add_observations(0.0, Observations(np.zeros(0), np.zeros(0)))
    start = slam.pose().mean
    stamps = np.arange(0.0, 0.8, 0.1)
    controls = np.column_stack([0.5 + 0.2 * np.sin(stamps), 0.4 * np.cos(3.0 * stamps)])
    for k, (t, u) in enumerate(zip(stamps, controls)):
        slam.add_control(t, u)
        if k == 3:
            slam.pose()                       # a flush within the step: the sensitivity carried over it
    slam.add_observations(0.8, Observations(np.zeros(0), np.zeros(0)))
    assert slam._noise.gain_names[-1] == DRIFT
    dts = np.full(stamps.size, 0.1)
    ends = [integrate_segments(replace(config.motion, turn_per_meter=KAPPA + h), start[None], np.zeros((1, 3, 3)),
                               controls, dts)[0][0] for h in (1e-5, -1e-5)]
    expected = (ends[0] - ends[1]) / 2e-5
    assert np.abs(expected).max() > 0.05
    np.testing.assert_allclose(slam._noise.sensitivities[-1][:, -1], expected, rtol=1e-4, atol=1e-7)


def _drive(kappa: float, steps: int, seed: int):
    """A unicycle among 16 landmarks, commanded (0.5 m/s, a slow weave) at 10 Hz, turning kappa x
    speed more than commanded; range-bearing scans of every landmark within 8 m at 5 Hz."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    landmarks = np.column_stack([7.0 * np.cos(angles), 7.0 * np.sin(angles)]) + rng.normal(0.0, 0.5, (16, 2))
    pose, dt = np.array([0.0, -3.0, 0.0]), 0.1
    for k in range(steps):
        t = k * dt
        v, omega = 0.5, 0.15 + 0.2 * np.sin(0.05 * t)
        yield "control", t, np.array([v, omega])
        rate = omega + kappa * v + rng.normal(0.0, 0.01)
        pose = pose + dt * np.array([v * np.cos(pose[2]), v * np.sin(pose[2]), rate])
        if k % 2 == 1:
            offset = landmarks - pose[:2]
            ranges = np.hypot(*offset.T)
            seen = ranges < 8.0
            bearings = np.arctan2(offset[:, 1], offset[:, 0]) - pose[2]
            bearings = np.angle(np.exp(1j * (bearings[seen] + rng.normal(0.0, 0.005, seen.sum()))))
            yield "scan", t + dt, Observations(ranges[seen] + rng.normal(0.0, 0.03, seen.sum()), bearings,
                                               ids=np.flatnonzero(seen))


def test_the_learner_finds_the_turn_per_metre_of_a_simulated_robot():
    """The robot turns 0.05 rad per metre more than commanded: learned alone (the gains right), the
    turn per metre comes into use within 0.01 rad/m of it."""
    config = SlamConfig(motion=_unicycle(sigma_speed=0.05, sigma_steering=0.05),
                        sensor=SensorConfig(max_range=10.0),
                        noise=replace(SlamConfig().noise, sigma_range=0.03, sigma_bearing=0.005, rho=0.0),
                        noise_learning=NoiseLearningConfig(enabled=True, learn=("motion_drift",),
                                                           replay_warmup=False))
    config = replace(config, filter=replace(config.filter, num_particles=30, seed=0)).validate()
    slam = OnlineEMSlam(config, initial_pose=(0.0, -3.0, 0.0), stamp=0.0)
    for kind, stamp, value in _drive(KAPPA, 1500, seed=1):
        (slam.add_control if kind == "control" else slam.add_observations)(stamp, value)
    learned = slam.learned_noise()
    assert learned["motion_gain_names"] == [DRIFT]
    assert learned["motion_gains_in_use"] == [True]
    assert learned["motion_gains"][0] == pytest.approx(KAPPA, abs=0.01)
    assert slam._noise.gains_in_use[0] == pytest.approx(KAPPA, abs=0.01)
