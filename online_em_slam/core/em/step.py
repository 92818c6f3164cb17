"""What one filter step hands to the EM update, and the interface every M-step variant offers.

The filter step (core/filter/slam.py) computes the particles, their weights and the
observation terms; an M-step piece turns them into a new map.  Two pieces
implement :class:`MStep`: the seed's complete-data M-step (complete.py) and
the observed-information Newton step (observed.py).  ``em.m_step`` picks one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..mapping.landmarks import LandmarkTable
from ..weighted import weighted_pose_mean


@dataclass
class FilterStepData:
    """One filter step t, N particles, P associated observations.

    particles (N, 3) xi_t; weights (N,) w_t; log_weights_prev (N,) log w_{t-1};
    prior_weights (N,) normalised weights before the likelihood; ancestors (N,);
    transition_means (N, 3) and transition_covs (N, 3, 3): the Gaussian transition
    (T) from each particle at t-1; rows (P,) landmark rows; y (P, 2) observations;
    R (P, 2, 2) noise covariances; sensor (N, 3) sensor poses; nu (N, P, 2)
    innovations and H (N, P, 2, 2) Jacobians dh/dtheta at theta_{t-1};
    precision (N, P, 2, 2) R^-1 weighted by the mixture responsibilities;
    motion_mean (3,), motion_jacobian (3, 3), motion_cov (3, 3): the transition of
    the previous weighted mean pose (the linearisation track of the observed M-step);
    motion_gain_sensitivity (3, G): d motion_mean / d the gains (models/motion.py, GAIN_NAMES),
    when it learns the gains; serial (P, 2): each observation's serial correlation, by which R is
    weighed, when it decays with the viewpoint (else None: R is that of information_noise).
    """

    step: int
    particles: np.ndarray
    weights: np.ndarray
    log_weights_prev: np.ndarray
    prior_weights: np.ndarray
    ancestors: np.ndarray
    transition_means: np.ndarray
    transition_covs: np.ndarray
    rows: np.ndarray
    y: np.ndarray
    R: np.ndarray
    sensor: np.ndarray
    nu: np.ndarray
    H: np.ndarray
    precision: np.ndarray
    motion_mean: np.ndarray
    motion_jacobian: np.ndarray
    motion_cov: np.ndarray
    motion_gain_sensitivity: np.ndarray | None = None
    motion_cov_parts: np.ndarray | None = None     # (m, 3, 3): motion_cov's part from each noise group, unit scales
    mean_pose: np.ndarray | None = None            # (3,): pose_mean(), once computed
    serial: np.ndarray | None = None

    def pose_mean(self) -> np.ndarray:
        """The weighted mean pose xbar_t (3,), circular mean for the yaw; computed once per step."""
        if self.mean_pose is None:
            self.mean_pose = weighted_pose_mean(self.particles, self.weights)
        return self.mean_pose


class MStep(Protocol):
    """An EM update of the map theta from the E-step of one filter step."""

    def add_landmarks(self, count: int) -> None:
        """New rows at the end of the landmark table."""

    def keep_landmarks(self, keep: np.ndarray) -> None:
        """Rows removed from the landmark table (``keep`` False)."""

    def update(self, data: FilterStepData, table: LandmarkTable) -> np.ndarray | None:
        """Blend in the step's statistics and run the M-step on ``table.theta``.

        Returns the correction of the current pose implied by the new map (the
        filter shifts its particles by it), or None.
        """

    def restart_pose(self, pose: np.ndarray, pose_std, table: LandmarkTable, weights: np.ndarray) -> None:
        """The filter was re-initialised at ``pose`` (no motion since the last step); ``weights``
        (N,) are the normalised weights of the particles it replaced."""

    def covariances(self, rows: np.ndarray | slice) -> np.ndarray:
        """Landmark covariances (K, 2, 2) for the association gate and the likelihood."""

    def map_covariances(self) -> np.ndarray:
        """Landmark covariances (M, 2, 2) reported with the map."""

    def saved_arrays(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Per-landmark state for the map file (core/mapping/mapfile.py keys: count, inv_n,
        stats, spread, avg_stats, avg_count) at the estimates ``theta`` (M, 2).  ``stats``
        are complete-data statistics (A, b) with A^-1 b = theta whatever the M-step, so
        that either M-step can load the file."""

    def restore(self, arrays: dict[str, np.ndarray], theta: np.ndarray) -> None:
        """Continue from a loaded map file's arrays (landmarks appended to empty state)."""
