"""One scan per place (filter.minimum_travel_*): the rule, and the feeder that applies it to every estimator."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from online_em_slam.baselines import EkfSlam
from online_em_slam.core.config import SlamConfig
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.types import Observations
from online_em_slam.pipeline import CONTROL, OBSERVATIONS, ODOMETRY, Feeder, Input
from online_em_slam.pipeline.travel import MinimumTravel


def scan():
    return Observations(np.array([4.0, 6.0]), np.array([0.3, -0.4]), np.array([0, 1], dtype=np.int64))


def test_the_rule_distance_or_heading_since_the_last_used_scan():
    rule = MinimumTravel(0.1, 0.2)
    assert rule.due(np.array([0.0, 0.0, 0.0]))                     # the first scan
    rule.used(np.array([0.0, 0.0, 0.0]))
    assert not rule.due(np.array([0.05, 0.05, 0.1]))
    assert rule.due(np.array([0.08, 0.07, 0.0]))                   # 0.106 m
    assert rule.due(np.array([0.0, 0.0, -0.25]))                   # turned
    rule.used(np.array([0.0, 0.0, math.pi - 0.05]))
    assert not rule.due(np.array([0.0, 0.0, -math.pi + 0.05]))     # 0.1 rad across the wrap


@pytest.mark.parametrize("distance, heading", [(0.0, 0.0), (0.0, 0.3), (0.3, 0.0)])
def test_a_zero_threshold_never_triggers_alone_and_both_zero_take_every_scan(distance, heading):
    rule = MinimumTravel(distance, heading)
    rule.used(np.zeros(3))
    assert rule.enabled == (distance > 0 or heading > 0)
    assert rule.due(np.zeros(3)) == (not rule.enabled)
    assert rule.due(np.array([0.5, 0.0, 0.0])) == (distance > 0 or not rule.enabled)
    assert rule.due(np.array([0.0, 0.0, 0.5])) == (heading > 0 or not rule.enabled)


@pytest.mark.parametrize("make", [OnlineEMSlam, EkfSlam])
def test_standing_still_one_scan_is_used_then_none_until_the_robot_moves(make):
    config = SlamConfig.from_dict({"motion": {"model": "unicycle"},
                                   "filter": {"seed": 1, "num_particles": 10, "minimum_travel_distance": 0.05,
                                              "minimum_travel_heading": 0.05}})
    feeder = Feeder(make(config), "control")
    used = []
    t = 0.0
    for k in range(40):                                   # 2 s still, then 2 s at 0.2 m/s
        t = 0.05 * k
        feeder.apply(Input(t, CONTROL, payload=(0.0 if k < 20 else 0.2, 0.0)))
        if k % 4 == 3:
            used.append(feeder.apply(Input(t + 0.01, OBSERVATIONS, payload=scan())).report is not None)
    # still: the first scan only; moving at 0.2 m/s, 0.04 m per scan: every second one
    assert used == [True, False, False, False, False, False, True, False, True, False]
    assert feeder.drops == Counter(minimum_travel=7)


def test_by_default_every_scan_is_used():
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    feeder = Feeder(OnlineEMSlam(config), "odom")
    for k in range(10):
        feeder.apply(Input(0.1 * k, ODOMETRY, payload=(0.0, 0.0, 0.0)))
        assert feeder.apply(Input(0.1 * k + 0.01, OBSERVATIONS, payload=scan())).report is not None
    assert not feeder.drops
