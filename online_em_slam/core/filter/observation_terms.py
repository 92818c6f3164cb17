"""One scan's observation terms under theta_{t-1}: innovations, Jacobians, the particles'
log-likelihood and the noise model's responsibilities (docs/METHOD.md, "Filter step")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import ObservationNoiseConfig
from ..models.observation import (component_precision_weight, innovation, inv_det_2x2, landmark_jacobian,
                                  noise_covariance, noise_loglik, predict_observation)
from ..types import Observations


@dataclass
class ObservationTerms:
    """Per-scan observation terms under theta_{t-1}, N particles, P associated observations.

    y (P, 2), R (P, 2, 2), nu (N, P, 2) innovations, H (N, P, 2, 2) = dh/dtheta,
    precision (N, P, 2, 2) responsibility-weighted R^-1, log_likelihood (N,); serial (P, 2) each
    observation's serial correlation when it decays with the viewpoint (R is then weighed by it).
    """

    y: np.ndarray
    R: np.ndarray
    nu: np.ndarray
    H: np.ndarray
    precision: np.ndarray
    log_likelihood: np.ndarray
    serial: np.ndarray | None = None

    @classmethod
    def empty(cls, n: int) -> "ObservationTerms":
        return cls(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((n, 0, 2)), np.zeros((n, 0, 2, 2)),
                   np.zeros((n, 0, 2, 2)), np.zeros(n))


def observation_terms(y: np.ndarray, R: np.ndarray, theta_bar: np.ndarray, sensor: np.ndarray,
                      noise: ObservationNoiseConfig, weighting: np.ndarray,
                      landmark_cov: np.ndarray | None, given_pose_cov: np.ndarray | None = None) -> ObservationTerms:
    """The terms of observations ``y`` (P, 2) with noise ``R`` (P, 2, 2) of landmarks at
    ``theta_bar`` (P, 2), seen from the particles' sensor poses ``sensor`` (N, 3).

    The log-likelihood log g(y | xi^i, theta) sums over the landmarks seen often enough
    to weight (``weighting`` (P,)); ``landmark_cov`` (P, 2, 2), when given, is the
    landmarks' uncertainty, whose H Sigma_k H^T the innovation covariance then carries too.
    ``given_pose_cov`` (P, 2, 2), when given, is each landmark's covariance given the robot's
    pose (NaN: none yet): the noise law's responsibilities are then those of an innovation
    with covariance R + H Sigma H^T (docs/METHOD.md, "Responsibilities and the map's uncertainty").
    """
    nu = innovation(y, predict_observation(sensor[:, None, :], theta_bar[None]))       # (N, P, 2)
    H = landmark_jacobian(sensor[:, None, :], theta_bar[None])                      # (N, P, 2, 2)
    # R (P, 2, 2) broadcasts over the particles: the noise law's d2 and log det take its
    # inverse once per observation, not once per particle and observation.
    loglik, resp = noise_loglik(noise, nu, R)
    if given_pose_cov is not None:          # Gaussian noise: every responsibility is 1 either way
        known = np.isfinite(given_pose_cov[:, 0, 0])
        Sigma = np.where(known[:, None, None], given_pose_cov, 0.0)
        resp = noise_loglik(noise, nu, R + H @ Sigma[None] @ np.swapaxes(H, -1, -2))[1]
    if landmark_cov is not None and weighting.any():
        loglik, _ = noise_loglik(noise, nu, R + H @ landmark_cov[None] @ np.swapaxes(H, -1, -2))
    log_likelihood = (np.where(weighting[None, :], loglik, 0.0).sum(axis=1) if weighting.any()
                      else np.zeros(nu.shape[0]))
    R_inv, _ = inv_det_2x2(R)
    precision = R_inv[None] * component_precision_weight(noise, resp)[..., None, None]
    return ObservationTerms(y, R, nu, H, precision, log_likelihood)


def scan_noise(noise: ObservationNoiseConfig, obs: Observations, idx: np.ndarray) -> np.ndarray:
    """R (P, 2, 2) of the observations ``idx`` of a scan under ``noise``, or the stds they carry."""
    return noise_covariance(noise, obs.ranges[idx], None if obs.range_std is None else obs.range_std[idx],
                            None if obs.bearing_std is None else obs.bearing_std[idx])
