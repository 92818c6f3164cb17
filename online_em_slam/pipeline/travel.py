"""Observation updates only once the robot has moved (``filter.minimum_travel_*``).

A robot standing still reads each landmark again and again with nearly the same error:
MRCLAM's camera errors have a lag-1 correlation of 0.9 in range (docs/RESULTS.md,
"UTIAS MRCLAM"), which no longer decays while the viewpoint stays. Every estimator here
takes a scan's errors as independent of the last scan's, so a minute at a standstill
counts as hundreds of independent views of the same landmarks: their estimates settle
on one view's error with a covariance that says it is known to millimetres, and the
first view from elsewhere disagrees beyond every gate. Using a scan only after the
robot has travelled (as slam_toolbox's ``minimum_travel_distance`` / ``_heading`` and
Cartographer's motion filter do) keeps one view per place. The travel is that of the
estimator's predicted pose since the last used scan: the motion input's, not the
corrections of the updates in between.
"""
from __future__ import annotations

import math

import numpy as np


class MinimumTravel:
    """Whether a scan is due: the first is; then one after ``distance`` (m) of travel or
    ``heading`` (rad) of turning since the last used one (a zero threshold never triggers
    alone; both zero: every scan)."""

    def __init__(self, distance: float = 0.0, heading: float = 0.0) -> None:
        self.distance, self.heading = float(distance), float(heading)
        self.last: np.ndarray | None = None       # (x, y, yaw) after the last used scan

    @classmethod
    def from_config(cls, config) -> "MinimumTravel":
        """From ``config.filter`` (any estimator's SlamConfig; none: every scan)."""
        settings = getattr(config, "filter", None)
        return cls(getattr(settings, "minimum_travel_distance", 0.0), getattr(settings, "minimum_travel_heading", 0.0))

    @property
    def enabled(self) -> bool:
        return self.distance > 0.0 or self.heading > 0.0

    def due(self, pose: np.ndarray) -> bool:
        """A scan at the predicted pose (x, y, yaw) is used."""
        if not self.enabled or self.last is None:
            return True
        moved = math.hypot(pose[0] - self.last[0], pose[1] - self.last[1])
        turned = abs(math.remainder(pose[2] - self.last[2], 2.0 * math.pi))
        return (self.distance > 0.0 and moved >= self.distance) or (self.heading > 0.0 and turned >= self.heading)

    def used(self, pose: np.ndarray) -> None:
        """The pose after a used scan's update: travel counts from here."""
        self.last = np.array(pose[:3], dtype=float)
