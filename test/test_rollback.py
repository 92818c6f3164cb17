"""One bad input must not stop the estimator (reliability, second round, item 1):
per-observation stds are validated, and an input whose step raises is undone
(pipeline/rollback.py) so that the run goes on exactly as without it."""
from types import SimpleNamespace

import numpy as np
import pytest

from online_em_slam.baselines import EkfSlam
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.types import Observations
from online_em_slam.pipeline import CONTROL, OBSERVATIONS, Feeder
from online_em_slam.pipeline.inputs import Input
from online_em_slam.pipeline.rollback import Rollback
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


class _Recorder:
    """An estimator whose state is the stamps it took.  The calls are counted over every copy
    (``calls``, outside the state, as memory is); the calls numbered in ``fail_at`` raise after
    changing the state: a failure that depends on more than the inputs."""

    calls, fail_at = 0, frozenset()

    def __init__(self):
        self.applied = []

    def add_observations(self, stamp, _):
        type(self).calls += 1
        self.applied.append(stamp)
        if type(self).calls in self.fail_at:
            raise MemoryError("injected")

    def pose(self):
        return SimpleNamespace(mean=np.zeros(3), stamp=None)


def test_an_input_that_raises_again_when_applied_again_ends_the_reapplication_and_is_counted(monkeypatch):
    """Inputs 1-5 apply (calls 1-5); input 6 raises (call 6), so the copy taken before input 1
    is put back and inputs 1-5 applied again (calls 7-11); input 3 raises this time (call 9):
    the state is the copy with inputs 1-2, inputs 3-5 are lost and counted, and input 7 applies."""
    monkeypatch.setattr(_Recorder, "fail_at", frozenset({6, 9}))
    estimator = _Recorder()
    feeder = Feeder(estimator, "control")
    feeder.motion_seen = True
    observations = Observations(np.ones(1), np.zeros(1))
    fed = [feeder.apply(Input(float(k), OBSERVATIONS, payload=observations)) for k in range(1, 8)]
    assert [f.error is None for f in fed] == [True] * 5 + [False, True]
    assert estimator.applied == [1.0, 2.0, 7.0]
    assert feeder.drops["internal_error"] == 1 and feeder.drops["reapply_failed"] == 3
    feeder.rollback.restore()                          # the record since the copy matches the state
    assert estimator.applied == [1.0, 2.0, 7.0] and feeder.rollback.take_lost() == 0


def test_calls_that_took_long_are_not_applied_again_on_a_failure(monkeypatch):
    """A call holding the warm-up replay can take seconds: a copy follows calls that took
    MAX_REAPPLY_SECONDS in all, whatever the count of filter steps."""
    from online_em_slam.pipeline import rollback as rollback_module

    estimator = _Recorder()
    rollback = Rollback(estimator, period=100)
    rollback.call("add_observations", 1.0, None)
    assert len(rollback._since) == 1
    monkeypatch.setattr(rollback_module, "MAX_REAPPLY_SECONDS", 0.0)
    rollback.call("add_observations", 2.0, None)
    assert rollback._since == [] and rollback._saved["applied"] == [1.0, 2.0]


def test_the_fleet_nodes_estimate_hands_on_what_its_shared_rollback_lost(scenario):
    """ros/segment_link.py counts what a failed segment fold's restore lost through this."""
    from online_em_slam.ros.fleet_estimate import FleetEstimate

    config = slam_config_for(scenario, num_particles=10)
    estimate = FleetEstimate(config, [scenario.initial_pose] * 2, ("robot1", "robot2"), local_robot="robot1")
    estimate.feeds[1].shared.lost = 2            # every robot's feed shares the one rollback
    assert estimate.take_lost() == 2 and estimate.take_lost() == 0
