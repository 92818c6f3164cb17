"""The estimated trajectory behind ``~/path``, at a bounded cost per publish.

Rebuilding a nav_msgs/Path of every kept pose each map period cost 114 ms at
10^4 poses and 12 s / 914 MB at 10^6 (issue 12, defect 9).  Here the poses are
kept compactly (32 bytes each, in a ring of at most ``maxlen``) and the
published path holds at most ``max_poses`` of them: every ``stride``-th pose
by sequence number (stride a power of two, doubled as the trajectory grows)
plus the newest.  The selection is stable from one publish to the next, so the
PoseStamped messages are built once and cached: a publish builds only the
poses added since the last one and serialises at most ``max_poses + 1``.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from std_msgs.msg import Header

from . import conversions as conv


class PathHistory:
    """Ring of (stamp, x, y, yaw) with a cached, decimated nav_msgs/Path."""

    def __init__(self, maxlen: int, max_poses: int = 1000) -> None:
        self.maxlen = max(int(maxlen), 0)
        self.max_poses = max(int(max_poses), 2)
        self.clear()

    def clear(self) -> None:
        self._rows = np.zeros((0, 4))
        self._start = 0            # ring index of the oldest row
        self._size = 0
        self._next_seq = 0         # sequence number of the next appended pose
        self._cache: dict[int, PoseStamped] = {}

    def __len__(self) -> int:
        return self._size

    @property
    def first_seq(self) -> int:
        return self._next_seq - self._size

    def last_stamp(self) -> float | None:
        return float(self._rows[(self._start + self._size - 1) % len(self._rows), 0]) if self._size else None

    def append(self, stamp: float, mean) -> bool:
        """Add a pose (skipped if non-finite, a repeated stamp, or maxlen is 0)."""
        row = np.array([stamp, *np.asarray(mean, dtype=float).reshape(3)])
        if self.maxlen == 0 or not np.all(np.isfinite(row)) or self.last_stamp() == stamp:
            return False
        capacity = len(self._rows)
        if self._size == capacity and capacity < self.maxlen:
            self._reallocate(min(max(2 * capacity, 64), self.maxlen))
            capacity = len(self._rows)
        if self._size < capacity:
            self._rows[(self._start + self._size) % capacity] = row
            self._size += 1
        else:                                   # full: overwrite the oldest
            self._rows[self._start] = row
            self._start = (self._start + 1) % capacity
        self._next_seq += 1
        return True

    def revise(self, rows) -> None:
        """The poses up to the last of ``rows`` (n, 4) replaced by them: a replay filtered the past
        again (core/filter/warmup.py); the poses after it stay.  The sequence numbers start again."""
        rows = np.asarray(rows, dtype=float).reshape(-1, 4)
        rows = rows[np.isfinite(rows).all(axis=1)]
        if self.maxlen == 0 or not len(rows):
            return
        kept = self._ordered()
        merged = np.vstack([rows, kept[kept[:, 0] > rows[-1, 0]]])
        earlier = np.maximum.accumulate(np.concatenate([[-np.inf], merged[:-1, 0]]))
        merged = merged[merged[:, 0] > earlier][-self.maxlen:]       # stamps rising, as append keeps them
        self.clear()
        self._rows, self._size, self._next_seq = merged.copy(), len(merged), len(merged)

    def _ordered(self) -> np.ndarray:
        index = (self._start + np.arange(self._size)) % max(len(self._rows), 1)
        return self._rows[index]

    def _reallocate(self, capacity: int) -> None:
        rows = self._ordered()[-capacity:] if capacity else np.zeros((0, 4))
        self._rows = np.zeros((capacity, 4))
        self._rows[:len(rows)] = rows
        self._start, self._size = 0, len(rows)

    def resize(self, maxlen: int, max_poses: int | None = None) -> None:
        """Keep the newest ``maxlen`` poses (path_max_length changed at run time)."""
        self.maxlen = max(int(maxlen), 0)
        if max_poses is not None:
            self.max_poses = max(int(max_poses), 2)
        if self._size > self.maxlen or len(self._rows) > self.maxlen:
            self._reallocate(min(self._size, self.maxlen))

    def stride(self) -> int:
        """Smallest power of two that keeps the selection within max_poses."""
        stride = 1
        while -(-self._size // stride) > self.max_poses - 1:
            stride *= 2
        return stride

    def selected(self) -> np.ndarray:
        """Sequence numbers of the published poses: every stride-th, plus the newest."""
        if not self._size:
            return np.zeros(0, dtype=np.int64)
        stride = self.stride()
        first = -(-self.first_seq // stride) * stride
        seqs = np.arange(first, self._next_seq, stride, dtype=np.int64)
        newest = self._next_seq - 1
        return seqs if seqs.size and seqs[-1] == newest else np.append(seqs, newest)

    def to_msg(self, header: Header) -> Path:
        """The decimated path; PoseStamped messages are built once per selected pose."""
        seqs = self.selected()
        # Only the selected rows are read: copying the whole ring would cost O(maxlen) per publish.
        rows = self._rows[(self._start + seqs - self.first_seq) % max(len(self._rows), 1)]
        cache = {}
        for seq, row in zip(seqs.tolist(), rows):
            msg = self._cache.get(seq)
            if msg is None or msg.header.frame_id != header.frame_id:
                msg = PoseStamped(header=Header(stamp=conv.sec_to_stamp(row[0]), frame_id=header.frame_id),
                                  pose=conv.pose_msg(*row[1:]))
            cache[seq] = msg
        self._cache = cache
        return Path(header=header, poses=list(cache.values()))
