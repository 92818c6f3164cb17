"""One scan's observation terms under theta_{t-1}: innovations, Jacobians, the particles'
log-likelihood and the noise model's responsibilities (docs/METHOD.md, "Filter step")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import ObservationNoiseConfig
from ..models.observation import (component_precision_weight, innovation, inv_det_2x2, landmark_jacobian,
                                  noise_loglik, predict_observation)


@dataclass
class ObservationTerms:
    """Per-scan observation terms under theta_{t-1}, N particles, P associated observations.

    y (P, 2), R (P, 2, 2), nu (N, P, 2) innovations, H (N, P, 2, 2) = dh/dtheta,
    precision (N, P, 2, 2) responsibility-weighted R^-1, log_likelihood (N,).
    """

    y: np.ndarray
    R: np.ndarray
    nu: np.ndarray
    H: np.ndarray
    precision: np.ndarray
    log_likelihood: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "ObservationTerms":
        return cls(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((n, 0, 2)), np.zeros((n, 0, 2, 2)),
                   np.zeros((n, 0, 2, 2)), np.zeros(n))


def observation_terms(y: np.ndarray, R: np.ndarray, theta_bar: np.ndarray, sensor: np.ndarray,
                      noise: ObservationNoiseConfig, weighting: np.ndarray,
                      landmark_cov: np.ndarray | None) -> ObservationTerms:
    """The terms of observations ``y`` (P, 2) with noise ``R`` (P, 2, 2) of landmarks at
    ``theta_bar`` (P, 2), seen from the particles' sensor poses ``sensor`` (N, 3).

    The log-likelihood log g(y | xi^i, theta) sums over the landmarks seen often enough
    to weight (``weighting`` (P,)); ``landmark_cov`` (P, 2, 2), when given, is the
    landmarks' uncertainty, whose H Sigma_k H^T the innovation covariance then carries too.
    """
    n = sensor.shape[0]
    nu = innovation(np.broadcast_to(y, (n,) + y.shape).copy(),
                    predict_observation(sensor[:, None, :], theta_bar[None]))        # (N, P, 2)
    H = landmark_jacobian(sensor[:, None, :], theta_bar[None])                      # (N, P, 2, 2)
    log_likelihood = _weighting_loglik(noise, weighting, nu, H, R, landmark_cov)
    _, resp = noise_loglik(noise, nu, np.broadcast_to(R, H.shape))
    R_inv, _ = inv_det_2x2(R)
    precision = R_inv[None] * component_precision_weight(noise, resp)[..., None, None]
    return ObservationTerms(y, R, nu, H, precision, log_likelihood)


def _weighting_loglik(noise, weighting, nu, H, R, landmark_cov) -> np.ndarray:
    """log g(y | xi^i, theta) summed over the ``weighting`` landmarks (N,)."""
    if not weighting.any():
        return np.zeros(nu.shape[0])
    S = np.broadcast_to(R, H.shape).copy()
    if landmark_cov is not None:
        S += H @ landmark_cov[None] @ np.swapaxes(H, -1, -2)
    loglik, _ = noise_loglik(noise, nu, S)
    return np.where(weighting[None, :], loglik, 0.0).sum(axis=1)
