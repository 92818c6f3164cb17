"""Reliability item 8: one scan of 1,000 unknown-id observations (a flood of clutter).

Before the bound, such a scan created one landmark per observation that survived
the merging (266 of 1,000 on the simulated run below, 611 with 5 cm range noise),
each a row of the observed M-step's joint system, which is O(M^2) in memory and
whose marginals cost O(M^3): 87 MB for the flood and the ten steps after it.  Now
a scan creates at most ``association.max_new_landmarks_per_scan`` landmarks (the
nearest; the others counted under ``new_landmark_limit``), and the map the node
publishes holds the confirmed landmarks only (test_reliability_node.py).
"""
import time
import tracemalloc

import numpy as np
import pytest

from online_em_slam.core.config import AssociationConfig
from online_em_slam.core.filter.association import merge_close, nearest_first
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.types import Observations
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

N_FLOOD = 1000
LIMIT = AssociationConfig().max_new_landmarks_per_scan


def flood(n: int = N_FLOOD, seed: int = 1, ids=None) -> Observations:
    """n observations at random ranges (within the 30 m sensor range) and bearings (in front)."""
    rng = np.random.default_rng(seed)
    ids = np.full(n, -1, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
    return Observations(rng.uniform(1.0, 30.0, n), rng.uniform(-np.pi / 2, np.pi / 2, n), ids)


def empty() -> Observations:
    return Observations(np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64))


def small(known_ids: bool = True) -> OnlineEMSlam:
    """An estimator at the origin with an empty map."""
    config = slam_config_for(simulate(ScenarioConfig(known_ids=known_ids, n_steps=1)), num_particles=20)
    return OnlineEMSlam(config, initial_pose=np.zeros(3))


def fresh_run(sigma_range=None):
    sc = simulate(ScenarioConfig(known_ids=False, n_steps=200))
    config = slam_config_for(sc, num_particles=100)
    if sigma_range is not None:                     # a finer sensor merges fewer flood points
        config.noise.sigma_range, config.noise.rho = sigma_range, 0.0
    slam = OnlineEMSlam(config, initial_pose=sc.initial_pose)
    for step in sc.steps:
        feed(slam, step)
    return slam, sc.steps[-1].stamp


@pytest.mark.parametrize("sigma_range", [None, 0.05])
def test_flood_scan_creates_a_bounded_number_of_landmarks_in_bounded_memory_and_time(sigma_range):
    slam, stamp = fresh_run(sigma_range)
    before = slam.landmarks()
    assert len(before) and before.confirmed.all()
    drops_before = slam.drops["new_landmark_limit"]

    tracemalloc.start()
    started = time.perf_counter()
    report = slam.add_observations(stamp + 0.2, flood())
    step_time = time.perf_counter() - started
    for k in range(10):                              # the segment closes: the flood reaches the joint system
        slam.add_observations(stamp + 0.4 + 0.2 * k, empty())
    slam.landmarks()                                 # the marginals the node publishes
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()

    assert report.n_created <= LIMIT
    assert len(slam.landmarks()) <= len(before) + LIMIT
    limited = slam.drops["new_landmark_limit"] - drops_before
    assert limited > 0 and report.dropped["new_landmark_limit"] == limited
    # Every observation is accounted for: associated, created, or dropped by a named reason.
    merged = slam.drops["merged_new_landmark"]
    assert report.n_associated + sum(report.dropped.values()) + merged >= N_FLOOD
    assert step_time < 2.0, step_time
    assert peak < 10e6, f"{peak / 1e6:.1f} MB"      # 17.5 MB (611 landmarks: 87 MB) before the bound
    # The flood's landmarks are tentative: the confirmed map is the one before.
    confirmed = slam.landmarks(confirmed_only=True)
    np.testing.assert_array_equal(np.sort(confirmed.ids), np.sort(before.ids))


def test_the_nearest_creations_are_kept():
    slam = small(known_ids=False)
    slam.config.association.max_new_landmarks_per_scan = 5
    ranges = np.arange(20, 0, -1, dtype=float)       # 20 m ... 1 m, far apart: no merging
    bearings = np.linspace(-1.0, 1.0, 20)
    report = slam.add_observations(0.2, Observations(ranges, bearings, np.full(20, -1, dtype=np.int64)))
    assert report.n_created == 5 and report.dropped["new_landmark_limit"] == 15
    distance = np.hypot(*slam.landmarks().positions.T)
    assert np.all(distance < 6.0), distance            # the five nearest, 1..5 m


def test_known_id_creations_are_bounded_too():
    slam = small()
    report = slam.add_observations(0.2, flood(ids=np.arange(N_FLOOD)))
    assert report.n_created == LIMIT and len(slam.landmarks()) == LIMIT
    assert slam.drops["new_landmark_limit"] == N_FLOOD - LIMIT
    # Ids stay those of the observations kept.
    assert set(slam.landmarks().ids) <= set(range(N_FLOOD))


def test_the_scan_limit_and_the_map_limit_both_count():
    slam = small()
    slam.config.association.max_landmarks = 30
    report = slam.add_observations(0.2, flood(ids=np.arange(N_FLOOD)))
    assert report.n_created == 30
    assert report.dropped["new_landmark_limit"] == N_FLOOD - LIMIT
    assert report.dropped["map_full"] == LIMIT - 30


def test_nearest_first():
    np.testing.assert_array_equal(nearest_first(np.array([3.0, 1.0, 2.0, 1.0]), 2), [False, True, False, True])
    np.testing.assert_array_equal(nearest_first(np.array([3.0, 1.0]), 5), [True, True])
    np.testing.assert_array_equal(nearest_first(np.array([2.0, 2.0, 2.0]), 2), [True, True, False])
    assert nearest_first(np.zeros(0), 3).shape == (0,)


def test_merge_close_keeps_the_earlier_of_close_pairs():
    """The greedy rule against a brute-force reference: in order, a landmark is kept
    unless an earlier kept one lies within the radius."""
    rng = np.random.default_rng(3)
    for n, radius in ((1, 1.0), (2, 1.0), (50, 1.0), (300, 0.7), (300, 3.0)):
        positions = rng.uniform(-10.0, 10.0, (n, 2))
        keep = np.ones(n, dtype=bool)
        for i in range(n):
            if keep[i]:
                later = np.arange(n) > i
                keep[later & (np.hypot(*(positions - positions[i]).T) <= radius)] = False
        kept, idx = merge_close(positions, np.arange(n) + 100, radius)
        np.testing.assert_array_equal(idx, np.flatnonzero(keep) + 100)
        np.testing.assert_array_equal(kept, positions[keep])


def test_a_flood_of_coincident_points_is_one_landmark_quickly():
    """1,000 points at one place: half a million close pairs, which a loop over the pairs
    took 2.5 s to merge; the loop over kept landmarks does it in one query."""
    slam = small(known_ids=False)
    rng = np.random.default_rng(0)
    started = time.perf_counter()
    report = slam.add_observations(0.2, Observations(10.0 + rng.normal(0.0, 0.01, N_FLOOD), np.zeros(N_FLOOD),
                                                     np.full(N_FLOOD, -1, dtype=np.int64)))
    assert report.n_created == 1 and slam.drops["merged_new_landmark"] == N_FLOOD - 1
    assert time.perf_counter() - started < 1.0


def test_the_limit_is_a_validated_parameter():
    with pytest.raises(ValueError, match=r"association\.max_new_landmarks_per_scan"):
        AssociationConfig(max_new_landmarks_per_scan=0).validate()
