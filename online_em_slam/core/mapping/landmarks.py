"""The landmark table: the map parameter theta and its per-landmark bookkeeping.

One row per landmark.  The EM pieces keep their own per-landmark arrays (the
sufficient statistics, the information matrix) and follow the table's rows
through :meth:`LandmarkTable.add` / :meth:`LandmarkTable.keep` callbacks, so a
created or pruned landmark can never leave two arrays out of step.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LandmarkTable:
    """theta (M, 2), ids (M,), observation counts, creation step, confirmed flag, and whether an
    unconfirmed landmark may be pruned: one created from an observation without an id may be
    noise, one whose id the sensor read is known to exist and waits to be seen again (as the
    baselines' LandmarkBook)."""

    theta: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    n_obs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    created: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    prunable: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    _ROW_FIELDS = ("theta", "ids", "n_obs", "created", "confirmed", "prunable")

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def add(self, positions: np.ndarray, ids: np.ndarray, step: int, prunable=True) -> np.ndarray:
        """Append landmarks at ``positions`` (k, 2), ``prunable`` (k,) or one flag for all; their rows."""
        k = positions.shape[0]
        start = len(self)
        self.theta = np.vstack([self.theta, positions.reshape(k, 2)])
        self.ids = np.concatenate([self.ids, np.asarray(ids, dtype=np.int64)])
        self.n_obs = np.concatenate([self.n_obs, np.zeros(k, dtype=np.int64)])
        self.created = np.concatenate([self.created, np.full(k, step, dtype=np.int64)])
        self.confirmed = np.concatenate([self.confirmed, np.zeros(k, dtype=bool)])
        self.prunable = np.concatenate([self.prunable, np.broadcast_to(np.asarray(prunable, dtype=bool), (k,))])
        return np.arange(start, start + k)

    def keep(self, keep: np.ndarray) -> None:
        for name in self._ROW_FIELDS:
            setattr(self, name, getattr(self, name)[keep])

    def rows_of_ids(self, ids: np.ndarray) -> np.ndarray:
        """Row of each landmark id, -1 where the id is not in the map (sorted search)."""
        if not len(self):
            return np.full(np.shape(ids), -1, dtype=int)
        order = np.argsort(self.ids, kind="stable")
        sorted_ids = self.ids[order]
        pos = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.size - 1)
        return np.where(sorted_ids[pos] == ids, order[pos], -1).astype(int)

    def next_ids(self, count: int, pending: list[int]) -> list[int]:
        """Ids for landmarks created from unknown-id observations: above every id in use."""
        start = max([int(self.ids.max()) if len(self) else -1] + pending) + 1
        return list(range(start, start + count))

    def stale(self, step: int, confirm_observations: int, tentative_timeout: int) -> np.ndarray:
        """Confirm landmarks seen often enough; True for unconfirmed prunable ones past their timeout."""
        self.confirmed |= self.n_obs >= confirm_observations
        return ~self.confirmed & self.prunable & (step - self.created > tentative_timeout)
