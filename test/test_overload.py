"""Overload (reliability, second round, item 2): a feed faster than the estimator sheds
observation updates, never a motion input, keeps the lag within ``max_lag`` and counts the
shedding as ``overload``; no loss is reported when none happened.

Deterministic: a discrete-event model of the node.  Inputs are published at their stamp
divided by the replay rate; the node takes them one at a time in arrival order (an
executor's queue), each message costing ``MESSAGE_COST`` wall seconds and each observation
update ``UPDATE_COST``; its clock is the replay's /clock (the newest stamp published).
"""
from __future__ import annotations

import math
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

from online_em_slam.core.types import Observations
from online_em_slam.pipeline import OBSERVATIONS, ODOMETRY, InputPipeline
from online_em_slam.pipeline.lag import InputLag

MESSAGE_COST = 2e-4      # wall s per message taken
UPDATE_COST = 0.010      # wall s per observation update: 5 Hz scans at 20x are 1 s of work per s


class Model:
    """The wall clock of the model and what it takes: shared by the estimator and the test."""

    def __init__(self) -> None:
        self.wall = 0.0
        self.published = -math.inf       # newest stamp published: the replay's /clock

    def stamp_clock(self) -> float:
        return self.published


class CostlyEstimator:
    """Records what it is fed; an observation update costs UPDATE_COST of the model's wall time."""

    model: Model = None                  # class attribute: the Rollback's copies share it

    def __init__(self) -> None:
        self.moves: list[float] = []
        self.updates: list[float] = []
        self.last_stamp = None

    def add_odometry(self, t, pose) -> bool:
        self.moves.append(t)
        self.last_stamp = t
        return True

    def add_observations(self, t, observations):
        CostlyEstimator.model.wall += UPDATE_COST
        self.updates.append(t)
        self.last_stamp = t
        return SimpleNamespace(ess=1.0, dropped={})

    def pose(self):
        return SimpleNamespace(stamp=self.last_stamp, mean=np.zeros(3))


def scan():
    return Observations(np.array([5.0]), np.zeros(1), np.full(1, -1, dtype=np.int64))


def run(rate: float, seconds: float = 30.0, shedding: bool = True, max_lag: float = 1.0, clock: bool = True):
    """Odometry at 40 Hz and scans at 5 Hz replayed at ``rate``; returns (pipeline, estimator,
    lag of every applied motion input measured against the replay's clock, published counts)."""
    model = Model()
    CostlyEstimator.model = model
    estimator = CostlyEstimator()
    motion_lags = []

    def applied(item, fed):
        if item.kind == ODOMETRY:
            motion_lags.append(model.published - item.stamp)

    pipeline = InputPipeline(estimator, "odom", input_delay=1.0, jump_threshold=1.0, shedding=shedding,
                             on_applied=applied, clock=lambda: model.wall, max_lag=max_lag,
                             stamp_clock=model.stamp_clock if clock else None)
    messages = [(0.025 * k, ODOMETRY, (0.025 * k, 0.0, 0.0)) for k in range(1, int(seconds / 0.025) + 1)]
    messages += [(0.2 * k + 0.01, OBSERVATIONS, scan()) for k in range(1, int(seconds / 0.2))]
    messages.sort(key=lambda m: m[0])
    queue, i = deque(), 0
    while i < len(messages) or queue:
        while i < len(messages) and messages[i][0] / rate <= model.wall:
            queue.append(messages[i])
            model.published = messages[i][0]
            i += 1
        if not queue:
            model.wall = messages[i][0] / rate
            continue
        stamp, kind, payload = queue.popleft()
        model.wall += MESSAGE_COST
        pipeline.push(kind, stamp, payload, model.wall)
    pipeline.flush()
    published = {ODOMETRY: sum(m[1] == ODOMETRY for m in messages),
                 OBSERVATIONS: sum(m[1] == OBSERVATIONS for m in messages)}
    return pipeline, estimator, np.array(motion_lags), published


def losses(drops) -> dict:
    return {k: v for k, v in drops.items() if k.endswith("_lost") or k in ("out_of_order", "message_lost")}


def test_a_feed_faster_than_the_estimator_sheds_scans_never_motion_and_bounds_the_lag():
    pipeline, estimator, lags, published = run(rate=20.0)
    drops = pipeline.drops
    assert len(estimator.moves) == published[ODOMETRY]           # every motion input applied, in order
    assert estimator.moves == sorted(estimator.moves)
    assert drops["overload"] > 0                                 # scans shed, counted as overload
    assert drops["overload"] + len(estimator.updates) == published[OBSERVATIONS]
    assert not losses(drops), drops                              # nothing was lost: none reported
    assert lags.max() <= 1.0, lags.max()                         # the lag stays within max_lag
    assert pipeline.lag.max_lag <= 1.0


def test_without_shedding_the_same_feed_falls_behind():
    """The model is a real overload: the same feed without shedding (offline, reliable inputs) lags
    far beyond the bound, and nothing is shed or lost."""
    pipeline, estimator, lags, published = run(rate=20.0, shedding=False)
    assert lags.max() > 3.0
    assert pipeline.drops["overload"] == 0 and not losses(pipeline.drops)
    assert len(estimator.updates) == published[OBSERVATIONS]


def test_the_bound_is_the_parameter():
    lags = {limit: run(rate=20.0, max_lag=limit)[2].max() for limit in (0.5, 2.0)}
    assert lags[0.5] <= 0.5 and 0.5 < lags[2.0] <= 2.0, lags


def test_a_feed_the_estimator_keeps_up_with_sheds_nothing_and_reports_no_loss():
    pipeline, estimator, lags, published = run(rate=2.0, seconds=10.0)
    assert pipeline.drops["overload"] == 0 and not losses(pipeline.drops), pipeline.drops
    assert len(estimator.updates) == published[OBSERVATIONS] and len(estimator.moves) == published[ODOMETRY]
    assert lags.max() < 0.2 + 0.01       # the merge's own wait: odometry waits for the next scan


def test_without_a_clock_the_lag_is_measured_on_the_queue_alone():
    """Offline (no clock): what waits in the pipeline's own queue is the lag; shedding still
    bounds it when asked, and the merge's silence rule is not touched."""
    pipeline, estimator, lags, published = run(rate=20.0, clock=False)
    assert len(estimator.moves) == published[ODOMETRY] and not losses(pipeline.drops)
    assert pipeline.path.sequencer.consumer_behind is False


def test_a_node_behind_its_inputs_keeps_waiting_for_motion_and_sheds_observations():
    """The executor holds the odometry while clouds keep coming, each callback later than the
    last: the odometry looks silent for more than input_delay.  Without the clock its messages
    come out of order (dropped); with it the node knows its queues hold messages, waits, and
    sheds the observation updates that are too far behind."""
    def feed(with_clock: bool):
        model = Model()
        CostlyEstimator.model = model
        estimator = CostlyEstimator()
        pipeline = InputPipeline(estimator, "odom", input_delay=1.0, jump_threshold=1.0, shedding=True,
                                 clock=lambda: model.wall, max_lag=1.0,
                                 stamp_clock=(lambda: model.wall) if with_clock else None)
        model.wall = 0.0
        pipeline.push(ODOMETRY, 0.0, (0.0, 0.0, 0.0), 0.0)
        for k in range(1, 10):                   # clouds arrive, ever later; odometry waits in the executor
            model.wall = 0.3 * k
            pipeline.push(OBSERVATIONS, 0.1 * k, scan(), model.wall)
        model.wall = 3.0
        pipeline.release(3.0)
        for k in range(1, 10):                   # then the odometry arrives, 3 s late
            model.wall = 3.0 + 0.01 * k
            pipeline.push(ODOMETRY, 0.1 * k, (0.1 * k, 0.0, 0.0), model.wall)
        pipeline.flush()
        return pipeline.drops, estimator

    drops, estimator = feed(with_clock=False)
    assert drops["out_of_order"] > 0                              # taken for silent: motion out of order
    drops, estimator = feed(with_clock=True)
    assert drops["out_of_order"] == 0 and drops["overload"] > 0, drops
    assert len(estimator.moves) == 10                             # every motion input used


def test_input_lag_baseline_is_each_streams_own_delay():
    """A detector whose stamps are 0.4 s old on arrival (its processing) is not late; one
    0.9 s old after that is 0.5 s late.  Stamps ahead of the clock (before /clock, a jump back) are
    not measured."""
    now = [10.0]
    lag = InputLag(limit=1.0, clock=lambda: now[0], ahead_tolerance=1.0, silence=1.0)
    lag.arrived(OBSERVATIONS, 9.6, wall=0.0)
    lag.arrived(ODOMETRY, 10.0, wall=0.0)
    assert lag.lateness(0.0) == pytest.approx(0.0) and not lag.behind(0.0)
    now[0] = 11.0
    lag.arrived(OBSERVATIONS, 10.1, wall=0.5)
    assert lag.lateness(0.5) == pytest.approx(0.5) and not lag.behind(0.5)
    lag.arrived(OBSERVATIONS, 10.0, wall=0.6)
    assert lag.behind(0.6) and not lag.behind(2.0)              # nothing came since: queues empty
    assert lag.applied(OBSERVATIONS, 10.0) == pytest.approx(0.6) and lag.shed(0.6)
    lag.arrived(ODOMETRY, 50.0, wall=0.7)                       # far ahead of the clock: not measured
    assert lag.lateness(0.7) == pytest.approx(0.6)
    now[0] = 0.0                                                # no clock yet (sim time before /clock)
    assert lag.applied(ODOMETRY, 10.0) == 0.0
