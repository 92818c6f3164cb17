"""Duplicate landmarks merged (core/em/merge.py, docs/METHOD.md "Duplicate landmarks").

The merge conditions the map's Gaussian on theta_i = theta_j; checked against the same
Gaussian in information form with the constraint as a stiff factor (k A'A, A = [I, -I]),
solved and inverted densely.  The test's d2 against A Sigma A' of the dense covariance.
"""
import copy

import numpy as np
import pytest

from online_em_slam.core.config import AssociationConfig, SlamConfig
from online_em_slam.core.em.merge import DuplicateMerger
from online_em_slam.core.em.observed import ObservedInformationEM
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.mapping.landmarks import LandmarkTable
from online_em_slam.core.types import Observations, split_decisions
from test_observed_covariance import _both
from test_observed_information import _problem

STIFF = 1e10


@pytest.fixture(scope="module")
def forms():
    return _both(_problem(), 10)


def _selector(n: int, i: int, j: int) -> np.ndarray:
    """A (2, n) over [dx_key (3); theta (2 per landmark)]: theta_i - theta_j."""
    A = np.zeros((2, n))
    A[:, 3 + 2 * i:5 + 2 * i] = np.eye(2)
    A[:, 3 + 2 * j:5 + 2 * j] = -np.eye(2)
    return A


def test_the_merge_test_is_the_constraints_chi_square_under_the_joint_gaussian(forms):
    info, cov = forms
    mean = np.linalg.solve(info.info, info.vector)
    full = np.linalg.inv(info.info)
    for i, j in [(0, 1), (1, 3), (4, 2)]:
        A = _selector(full.shape[0], i, j)
        a = A @ mean
        assert cov.equality_d2(np.array([i]), np.array([j]))[0] == pytest.approx(
            float(a @ np.linalg.solve(A @ full @ A.T, a)), rel=1e-7)


def test_merging_conditions_the_gaussian_on_the_two_landmarks_being_one(forms):
    info, cov = forms
    cov = copy.deepcopy(cov)
    i, j = 1, 3
    A = _selector(info.info.shape[0], i, j)
    stiff = info.info + STIFF * A.T @ A                  # the constraint as a factor with no pull
    mean = np.linalg.solve(stiff, info.vector)
    full = np.linalg.inv(stiff)
    keep = np.r_[np.arange(3), [3 + 2 * k + d for k in range(5) if k != j for d in range(2)]]
    cov.condition_equal(i, j)
    cov.keep_landmarks(np.arange(5) != j)
    theta, dx_key = cov.solve()
    assert theta.shape == (4, 2)
    assert np.allclose(np.r_[dx_key, theta.ravel()], mean[keep], atol=1e-6)
    blocks = full[np.ix_(keep, keep)]
    marginals = np.array([blocks[3 + 2 * k:5 + 2 * k, 3 + 2 * k:5 + 2 * k] for k in range(4)])
    assert np.allclose(cov.landmark_covariances(), marginals, rtol=1e-5, atol=1e-9)


def _table(theta, confirmed, ids=None):
    table = LandmarkTable()
    n = len(theta)
    table.add(np.asarray(theta, dtype=float), np.arange(n) if ids is None else ids, 0, True)
    table.confirmed[:] = confirmed
    table.n_obs[:] = [9, 4, 6, 5][:n]
    return table


class _Store:
    """d2 = squared distance / 0.01: only the merger's choices are under test."""

    def __init__(self, table):
        self.table, self.slot = table, np.arange(len(table))

    def equality_d2(self, i, j):
        return np.sum((self.table.theta[i] - self.table.theta[j]) ** 2, axis=-1) / 0.01


def test_the_merger_takes_the_nearest_compatible_pair_of_confirmed_landmarks_never_seen_together():
    table = _table([[0, 0], [0.2, 0], [0.05, 0.02], [5, 5]], [True, True, True, True])
    merger = DuplicateMerger(0.999, 2.0)               # gate 13.8: within 0.37 m here
    store = _Store(table)
    recent = np.array([1, 2])
    assert merger.best_pair(table, store, recent) == (0, 2)      # d2 0.29, the survivor the better seen
    merger.seen_together(np.array([0, 2]))
    assert merger.best_pair(table, store, recent) == (2, 1)      # 0-2 were seen in one scan
    table.confirmed[1] = False
    assert merger.best_pair(table, store, recent) is None          # a tentative landmark waits
    table.confirmed[1] = True
    table.prunable[:] = False                                     # made with a sensor id: never merged
    assert merger.best_pair(table, store, recent) is None


def test_a_merged_landmark_keeps_what_its_duplicate_was_seen_with():
    merger = DuplicateMerger(0.999, 2.0)
    merger.seen_together(np.array([3, 7]))
    merger.merged(survivor=5, duplicate=7)
    assert 3 in merger.together[5] and 5 in merger.together[3] and 7 not in merger.together


def test_merging_is_for_one_robot_in_covariance_form():
    config = SlamConfig()
    assert ObservedInformationEM(config, np.zeros(3)).merger is not None
    assert ObservedInformationEM(config, np.zeros((2, 3))).merger is None
    config.em.map_form = "information"
    assert ObservedInformationEM(config, np.zeros(3)).merger is None
    config = SlamConfig(association=AssociationConfig(merge_probability=0.0))
    assert ObservedInformationEM(config, np.zeros(3)).merger is None


def test_no_merge_is_offered_where_the_difference_has_no_spread(forms):
    _, cov = forms
    cov = copy.deepcopy(cov)
    si, sj = cov.slot[0] + np.arange(2), cov.slot[1] + np.arange(2)
    cov.cov[np.ix_(sj, sj)] = cov.cov[np.ix_(si, si)]                 # theta_0 - theta_1 exactly known
    cov.cov[np.ix_(si, sj)] = cov.cov[np.ix_(sj, si)] = cov.cov[np.ix_(si, si)]
    assert np.isinf(cov.equality_d2(np.array([0]), np.array([1]))[0])


class _MergingEveryStep(ObservedInformationEM):
    """The observed M-step as if it merged a duplicate at every update."""

    def update(self, data, table, robot=0):
        correction = super().update(data, table, robot)
        self.merges += 1
        return correction


def test_a_merge_is_counted_among_the_estimators_decisions():
    slam = OnlineEMSlam(SlamConfig(), m_step_factory=lambda config, pose, rng: _MergingEveryStep(config, pose))
    for step in range(1, 4):
        slam.add_control(0.2 * step, np.array([1.0, 0.0]))
        slam.add_observations(0.2 * step, Observations(np.array([5.0]), np.array([0.1])))
    drops, decided = split_decisions(slam.drops)
    assert decided["merged_duplicate_landmark"] == 3 and "merged_duplicate_landmark" not in drops


def test_a_deep_copy_of_the_merger_is_equal_and_shares_no_set():
    """The rollback's checkpoint deep-copies the estimator (pipeline/rollback.py): the merger's copy
    must hold the same pairs and go its own way afterwards."""
    merger = DuplicateMerger(0.999, 2.0)
    merger.seen_together(np.array([3, 7, 9]))
    merger.seen_together(np.array([7, 11]))
    twin = copy.deepcopy(merger)
    assert (twin.gate, twin.radius, twin.together) == (merger.gate, merger.radius, merger.together)
    twin.seen_together(np.array([3, 11]))
    twin.merged(7, 9)
    assert merger.together == {3: {3, 7, 9}, 7: {3, 7, 9, 11}, 9: {3, 7, 9}, 11: {7, 11}}
    memo = {}
    assert copy.deepcopy([merger, merger], memo)[1] is memo[id(merger)]     # one copy per object
