"""Plain data types exchanged with the estimators (the public API's nouns)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: Usable per-observation standard deviations (m, rad); 0 or NaN means "not given: use
#: the configured noise".  The ceilings are those of noise.sigma_range and noise.sigma_bearing; the
#: floor keeps 1/std^2 finite and the map's information well conditioned (a claimed
#: micrometre is no sensor's, 1e-200 would be infinite information).
POINT_STD_LIMITS = {"range_std": (1e-6, 100.0), "bearing_std": (1e-6, math.pi)}

#: Counted reasons that are the estimator's decisions about valid input, not input lost,
#: refused or faulty: a scan that saw nothing, a reading beyond the configured range, an
#: observation between the association and creation gates, a creation merged or held back,
#: two landmarks found to be one and merged (em/merge.py), no creation while relocalising,
#: controls the odometry model does not use.  /diagnostics
#: reports them as ``decided.*``, apart from the drops that turn its status to WARN.
DECISIONS = frozenset({"empty_cloud", "observation_out_of_range", "ambiguous_association", "merged_new_landmark",
                       "merged_duplicate_landmark", "new_landmark_limit", "relocalising",
                       "control_ignored_by_odometry_model"})


def split_decisions(counts: dict) -> tuple[dict, dict]:
    """(drops, decisions) of counts by reason (:data:`DECISIONS`)."""
    return ({k: v for k, v in counts.items() if k not in DECISIONS},
            {k: v for k, v in counts.items() if k in DECISIONS})


@dataclass
class Observations:
    """One scan of range-bearing observations in the sensor frame.

    bearing 0 is the sensor's x axis, counter-clockwise positive; id -1 means
    unknown identity (associate by likelihood).  range_std / bearing_std, when
    given (not 0 or NaN), override the configured noise per observation; outside
    ``POINT_STD_LIMITS`` (or infinite) the observation is unusable (:meth:`valid_std`).
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

    def valid_std(self) -> np.ndarray:
        """(n,) mask: each std is not given (0 or NaN: configured noise) or within POINT_STD_LIMITS."""
        valid = np.ones(len(self), dtype=bool)
        for name, (low, high) in POINT_STD_LIMITS.items():
            std = getattr(self, name)
            if std is not None:
                with np.errstate(invalid="ignore"):
                    valid &= (std == 0.0) | np.isnan(std) | ((std >= low) & (std <= high))
        return valid

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
