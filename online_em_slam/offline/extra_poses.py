"""Pose variables of a batch problem at stamps of one's choosing, between the scans' (offline/batch.py).

The batch has a pose variable at the start and at every scan the estimator filters.  A
measurement made at another time, such as a robot's read of another robot's barcode
(offline/robot_reads.py), needs the robot's pose at that time: :class:`ExtraPoses` adds a
variable there, the motion into it compounded from the inputs as a scan's is.  Splitting a
scan-to-scan motion in two leaves its compounded mean and, but for one step jitter, its
covariance as they were: the problem is the same problem with more variables.
"""
from __future__ import annotations

import numpy as np


class ExtraPoses:
    """:func:`.batch.collect_problem`'s pose variables in time order: the scans' and the extra
    stamps' (E,), each made once the inputs up to it are in, before any later input.

    ``book``: the problem's motion bookkeeping (its ``start``, ``motion_seen``, ``skipped``,
    ``input.last_stamp`` and ``cut(stamp) -> (increment (3,), covariance (3, 3))``); ``stamps``,
    ``increments``, ``covs``: the problem's lists, appended to in place.
    """

    def __init__(self, extra_poses, book, stamps: list, increments: list, covs: list) -> None:
        self.pending = list(np.unique(np.asarray(extra_poses, dtype=float)))[::-1]    # earliest last
        self.book, self.stamps, self.increments, self.covs = book, stamps, increments, covs

    def pose_variable(self, stamp: float, motion) -> None:
        """A pose variable at ``stamp`` (a scan's or an extra one) with the motion into it."""
        if not self.stamps:
            self.stamps.append(self.book.start)
        self.stamps.append(stamp)
        self.increments.append(motion[0])
        self.covs.append(motion[1])
        while self.pending and self.pending[-1] == stamp:       # this scan's variable serves it
            self.pending.pop()

    def before(self, stamp: float) -> None:
        """Variables at the extra stamps before ``stamp`` (the next input's)."""
        while self.pending and self.pending[-1] < stamp:
            self._make(self.pending.pop())

    def finish(self) -> None:
        """Extra stamps up to the last input get their variables; later ones are counted."""
        last = self.book.input.last_stamp
        while self.pending and last is not None and self.pending[-1] <= last:
            self._make(self.pending.pop())
        self.book.skipped["extra_pose_after_inputs"] += len(self.pending)
        self.pending = []

    def _make(self, stamp: float) -> None:
        book = self.book
        if not book.motion_seen:
            book.skipped["extra_pose_before_motion"] += 1
            return
        if stamp == (self.stamps[-1] if self.stamps else book.start):
            return                                              # the variable there already
        self.pose_variable(stamp, book.cut(stamp))
