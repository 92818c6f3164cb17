"""Plain data types exchanged with the estimators (the public API's nouns)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Observations:
    """One scan of range-bearing observations in the sensor frame.

    bearing 0 is the sensor's x axis, counter-clockwise positive; id -1 means
    unknown identity (associate by likelihood).  range_std / bearing_std, when
    given and finite and positive, override the configured noise per observation.
    """

    ranges: np.ndarray
    bearings: np.ndarray
    ids: np.ndarray | None = None
    range_std: np.ndarray | None = None
    bearing_std: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.ranges = np.atleast_1d(np.asarray(self.ranges, dtype=float))
        self.bearings = np.atleast_1d(np.asarray(self.bearings, dtype=float))
        n = self.ranges.shape[0]
        if self.bearings.shape != (n,):
            raise ValueError(f"bearings has shape {self.bearings.shape}, ranges has {n} entries")
        self.ids = (np.full(n, -1, dtype=np.int64) if self.ids is None
                    else np.atleast_1d(np.asarray(self.ids, dtype=np.int64)))
        if self.ids.shape != (n,):
            raise ValueError(f"ids has shape {self.ids.shape}, ranges has {n} entries")
        for name in ("range_std", "bearing_std"):
            value = getattr(self, name)
            if value is not None:
                value = np.atleast_1d(np.asarray(value, dtype=float))
                if value.shape != (n,):
                    raise ValueError(f"{name} has shape {value.shape}, ranges has {n} entries")
                setattr(self, name, value)

    def __len__(self) -> int:
        return int(self.ranges.shape[0])

    def subset(self, mask: np.ndarray) -> "Observations":
        pick = (lambda a: None if a is None else a[mask])
        return Observations(self.ranges[mask], self.bearings[mask], self.ids[mask],
                            pick(self.range_std), pick(self.bearing_std))


@dataclass
class PoseEstimate:
    """Pose mean (x, y, yaw) and its 3x3 covariance at ``stamp``."""

    stamp: float | None
    mean: np.ndarray
    covariance: np.ndarray


@dataclass
class LandmarkMap:
    """Landmark estimates: ids, positions (M, 2), covariances (M, 2, 2), observation counts."""

    ids: np.ndarray
    positions: np.ndarray
    covariances: np.ndarray
    n_obs: np.ndarray
    confirmed: np.ndarray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


@dataclass
class StepReport:
    """What one call to ``add_observations`` did."""

    n_observations: int = 0
    n_associated: int = 0
    n_created: int = 0
    n_pruned: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    ess: float = float("nan")
    duration: float = 0.0
