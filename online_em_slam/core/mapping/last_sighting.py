"""What was last recorded of each landmark, by landmark id (ids are stable when the landmark
table drops rows): the pose it was last seen from, its last residual."""
from __future__ import annotations

import numpy as np


class LastSightings:
    """Per landmark id, the latest row of ``width`` values recorded for it."""

    def __init__(self, width: int) -> None:
        self.ids = np.zeros(0, dtype=np.int64)              # sorted
        self.values = np.zeros((0, width))

    def recall(self, ids: np.ndarray) -> np.ndarray:
        """The rows last recorded for ``ids`` (P,) (P, width); NaN for an id never recorded."""
        ids = np.asarray(ids, dtype=np.int64)
        out = np.full((ids.size, self.values.shape[1]), np.nan)
        if self.ids.size:
            at = np.minimum(np.searchsorted(self.ids, ids), self.ids.size - 1)
            known = self.ids[at] == ids
            out[known] = self.values[at[known]]
        return out

    def record(self, ids: np.ndarray, values: np.ndarray) -> None:
        """``values`` (P, width) as the latest of ``ids`` (P,); of an id twice, its last row."""
        ids = np.asarray(ids, dtype=np.int64)
        if not ids.size:
            return
        last = ids.size - 1 - np.unique(ids[::-1], return_index=True)[1]       # each id's last row
        ids, values = ids[last], values[last]
        at = np.minimum(np.searchsorted(self.ids, ids), max(self.ids.size - 1, 0))
        known = (self.ids[at] == ids) if self.ids.size else np.zeros(ids.size, dtype=bool)
        self.values[at[known]] = values[known]
        if not known.all():
            merged = np.concatenate([self.ids, ids[~known]])
            order = np.argsort(merged, kind="stable")
            self.ids = merged[order]
            self.values = np.vstack([self.values, values[~known]])[order]
