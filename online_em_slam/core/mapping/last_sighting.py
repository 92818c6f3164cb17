"""What was last recorded of each landmark, by landmark id (ids are stable when the landmark
table drops rows): the pose it was last seen from, its last residual."""
from __future__ import annotations

import numpy as np


class LastSightings:
    """Per landmark id, the latest row of ``width`` values recorded for it.

    A scan touches a few ids and every filter step asks, so the rows sit in one array in
    the order the ids first came, found through a dictionary (a few dictionary lookups cost
    less than the numpy calls of a sorted search); row 0 is all NaN, the answer for an id
    never recorded.  Ids may be any integers (a sensor's own ids need not be small).
    """

    def __init__(self, width: int) -> None:
        self.rows: dict[int, int] = {}
        self.values = np.full((8, width), np.nan)      # row 0: never recorded; grown by doubling

    @property
    def ids(self) -> np.ndarray:
        """The ids recorded, sorted (M,)."""
        return np.array(sorted(self.rows), dtype=np.int64)

    def recall(self, ids: np.ndarray) -> np.ndarray:
        """The rows last recorded for ``ids`` (P,) (P, width); NaN for an id never recorded."""
        rows = self.rows
        return self.values[[rows.get(i, 0) for i in np.asarray(ids).tolist()]]

    def record(self, ids: np.ndarray, values: np.ndarray) -> None:
        """``values`` (P, width) as the latest of ``ids`` (P,); of an id twice, its last row."""
        rows = self.rows
        at = []
        for i in np.asarray(ids).tolist():
            row = rows.get(i)
            if row is None:
                row = rows[i] = len(rows) + 1
            at.append(row)
        if not at:
            return
        self._grow(len(rows) + 1)
        if len(set(at)) < len(at):                     # an id twice: numpy leaves unsaid which row a
            last = {row: k for k, row in enumerate(at)}  # repeated index keeps, so keep each id's last
            at, values = list(last), np.asarray(values)[list(last.values())]
        self.values[at] = values

    def _grow(self, size: int) -> None:
        capacity = self.values.shape[0]
        if size <= capacity:
            return
        while capacity < size:
            capacity *= 2
        grown = np.full((capacity, self.values.shape[1]), np.nan)
        grown[:self.values.shape[0]] = self.values
        self.values = grown
