"""One bad input must not stop the estimator (reliability, second round, item 1):
per-observation stds are validated, and an input whose step raises is undone
(pipeline/rollback.py) so that the run goes on exactly as without it."""
import numpy as np
import pytest

from online_em_slam.baselines import EkfSlam
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.types import Observations
from online_em_slam.pipeline import CONTROL, OBSERVATIONS, Feeder
from online_em_slam.pipeline.inputs import Input
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for


@pytest.fixture(scope="module")
def scenario():
    return simulate(ScenarioConfig(seed=1, n_steps=160))


def _inputs(scenario, poison_at=None, poison=None):
    items = []
    for k, step in enumerate(scenario.steps):
        items.append(Input(step.control_stamp, CONTROL, payload=step.control))
        items.append(Input(step.stamp, OBSERVATIONS, payload=step.observations()))
        if k == poison_at:
            items.append(Input(step.stamp + 1e-3, OBSERVATIONS, payload=poison(step)))
    return items


def _run(estimator, items):
    feeder = Feeder(estimator, "control")
    results = [feeder.apply(item) for item in items]
    return feeder, [r.trajectory_point for r in results if r.trajectory_point is not None]


def _bad_std_cloud(step):
    """The reported cloud: FLOAT64 stds of 1e200 and 1e-200 on alternating points."""
    n = len(step.ranges)
    std = np.where(np.arange(n) % 2 == 0, 1e200, 1e-200)
    return Observations(step.ranges, step.bearings, step.ids, std, std.copy())


@pytest.mark.parametrize("make", [OnlineEMSlam, EkfSlam])
def test_a_cloud_of_absurd_stds_is_refused_and_counted_and_the_estimator_keeps_updating(scenario, make):
    config = slam_config_for(scenario, num_particles=30)
    estimator = make(config, initial_pose=scenario.initial_pose)
    feeder, trajectory = _run(estimator, _inputs(scenario, poison_at=40, poison=_bad_std_cloud))
    n_points = len(scenario.steps[40].ranges)
    assert estimator.drops["invalid_std"] == n_points
    assert feeder.drops["internal_error"] == 0
    assert np.all(np.isfinite(np.asarray(trajectory)))
    assert np.all(np.isfinite(estimator.landmarks().positions))
    assert len(trajectory) >= len(scenario.steps)          # every later scan still updated the estimate


def test_valid_std_takes_zero_and_nan_as_not_given_and_refuses_the_rest():
    std = np.array([0.0, 0.1, 1e-200, 1e200, -0.1, np.nan, np.inf, 100.0, 1e-6, -np.inf])
    obs = Observations(np.ones(10), np.zeros(10), range_std=std)
    assert obs.valid_std().tolist() == [True, True, False, False, False, True, False, True, True, False]
    obs = Observations(np.ones(2), np.zeros(2), bearing_std=np.array([3.0, 3.2]))
    assert obs.valid_std().tolist() == [True, False]


class _FailOnce:
    """Wraps the observed M-step: at ``stamp`` it changes the map, then raises."""

    def __init__(self, estimator, stamp):
        self.estimator, self.stamp, self.inner = estimator, stamp, estimator._m_step

    def __getattr__(self, name):
        if name.startswith("__") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def update(self, data, table):
        if self.estimator._input.last_stamp == self.stamp:
            table.theta[:] = np.nan                        # half-updated state that would poison every later step
            raise FloatingPointError("injected failure")
        return self.inner.update(data, table)


def test_a_step_that_raises_is_undone_exactly_and_counted(scenario):
    config = slam_config_for(scenario, num_particles=30)
    clean = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    _, expected = _run(clean, _inputs(scenario))

    poison_stamp = scenario.steps[100].stamp + 1e-3
    failing = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    failing._m_step = _FailOnce(failing, poison_stamp)
    items = _inputs(scenario, poison_at=100, poison=lambda step: step.observations())
    feeder, got = _run(failing, items)

    assert feeder.drops["internal_error"] == 1
    assert len(got) == len(expected)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))   # as if the input never came
    np.testing.assert_array_equal(failing.landmarks().positions, clean.landmarks().positions)
