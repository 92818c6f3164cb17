"""Duplicate landmarks merged: a loop closure for landmarks made without an id.

docs/METHOD.md, "Duplicate landmarks".  Without ids a landmark seen again after the
pose has drifted falls outside the gates and is made a second time; the two then
share its observations, and both are confirmed.  The map's Gaussian (covariance form)
holds how far the newly mapped part may have turned against the old, so "i and j are
one landmark" is the linear hypothesis theta_i - theta_j = 0 on it, tested by

    d2 = a^T S^-1 a,   a = mu_i - mu_j,   S = Sigma_ii + Sigma_jj - Sigma_ij - Sigma_ji

against the chi-square(2) quantile of ``association.merge_probability``; accepted, the
Gaussian is conditioned on it (exact for a linear constraint: the whole map and the key
pose move, ObservedCovariance.condition_equal).  Only confirmed landmarks take part (a
tentative one's first observation is diffuse, so any d2 to it is small), and two
landmarks ever associated in one scan are two.
"""
from __future__ import annotations

import copy

import numpy as np

from ..mapping.landmarks import LandmarkTable
from ..models.observation import chi_square_2_quantile

# At most this many merges per segment end: each conditioning changes every other pair's d2.
MAX_MERGES = 5


class DuplicateMerger:
    """Which landmark ids were associated in one scan, and the merge test at segment ends."""

    def __init__(self, probability: float, radius: float) -> None:
        self.gate = chi_square_2_quantile(probability)
        self.radius = radius
        self.together: dict[int, set[int]] = {}

    def __deepcopy__(self, memo: dict) -> DuplicateMerger:
        """A copy whose sets are new: they hold ints only, so ``set(s)`` is a deep copy, made
        without copy.deepcopy's walk over every element (the rollback's checkpoint takes one
        every 64 filter steps; on Victoria Park that walk was three quarters of its cost)."""
        twin = DuplicateMerger.__new__(DuplicateMerger)
        memo[id(self)] = twin
        rest = {name: value for name, value in vars(self).items() if name != "together"}
        twin.__dict__.update(copy.deepcopy(rest, memo))
        twin.together = {i: set(seen) for i, seen in self.together.items()}
        return twin

    def seen_together(self, ids: np.ndarray) -> None:
        """The ids (P,) of one scan's associated landmarks (each with itself too: harmless)."""
        ids = ids.tolist()
        together = self.together
        for i in ids:
            seen = together.get(i)
            if seen is None:
                together[i] = set(ids)
            else:
                seen.update(ids)

    def merged(self, survivor: int, duplicate: int) -> None:
        """``duplicate``'s id is ``survivor``'s now: what it was seen with, the survivor was."""
        partners = self.together.pop(duplicate, set())
        self.together.setdefault(survivor, set()).update(partners - {duplicate})
        for other in partners:
            if other in self.together:
                self.together[other].discard(duplicate)
                self.together[other].add(survivor)

    def best_pair(self, table: LandmarkTable, store, recent: np.ndarray) -> tuple[int, int] | None:
        """(survivor row, duplicate row) of the pair with the least d2 below the gate, one of
        them among ``recent`` rows (seen in the segment just folded), both confirmed, made
        without an id, stored, never seen together and less than ``radius`` apart; else None.
        The survivor is the one with more observations."""
        mergeable = table.prunable & table.confirmed & (store.slot >= 0)
        recent, others = recent[mergeable[recent]], np.flatnonzero(mergeable)
        if not recent.size or others.size < 2:
            return None
        gap = table.theta[recent][:, None] - table.theta[others][None]
        near = (np.hypot(gap[..., 0], gap[..., 1]) < self.radius) & (recent[:, None] != others[None])
        r, o = np.nonzero(near)
        i, j = recent[r], others[o]
        d2 = store.equality_d2(i, j) if i.size else np.zeros(0)
        for k in np.argsort(d2):
            if not d2[k] < self.gate:
                return None
            if int(table.ids[j[k]]) not in self.together.get(int(table.ids[i[k]]), ()):
                a, b = int(i[k]), int(j[k])
                return (a, b) if table.n_obs[a] >= table.n_obs[b] else (b, a)
        return None
