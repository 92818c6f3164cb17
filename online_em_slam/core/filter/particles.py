"""Particle-filter primitives: weights, resampling, Gaussian draws (weighted moments: core/weighted.py)."""
from __future__ import annotations

import numpy as np

from ..models.angles import wrap_angle
from ..weighted import weighted_pose_covariance, weighted_pose_mean


def normalize_log_weights(log_weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised weights and the log of the mean unnormalised weight.

    Works in the log domain (subtract the max) so that likelihoods that all
    underflow still give proper weights.  Non-finite log-weights (NaN, -inf)
    get zero weight; if none is finite the weights fall back to uniform,
    which is the least-informative recovery from a degenerate update.
    """
    lw = np.where(np.isfinite(log_weights), log_weights, -np.inf)
    top = lw.max()
    if not np.isfinite(top):
        n = lw.shape[0]
        return np.full(n, 1.0 / n), -np.inf
    w = np.exp(lw - top)
    total = w.sum()
    return w / total, float(top + np.log(total / lw.shape[0]))


def effective_sample_size(weights: np.ndarray) -> float:
    """ESS = 1 / sum w_i^2 for normalised weights."""
    return float(1.0 / np.sum(weights * weights))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Ancestor indices by systematic resampling: one uniform, N stratified points.

    Unbiased: each index i is drawn N w_i times in expectation.
    """
    n = weights.shape[0]
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    return np.minimum(np.searchsorted(cumulative, positions, side="right"), n - 1)


def sample_gaussians(means: np.ndarray, covariances: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One draw from N(means[i], covariances[i]) per row, yaw wrapped."""
    chol = np.linalg.cholesky(covariances)
    draws = means + np.einsum("nij,nj->ni", chol, rng.standard_normal(means.shape))
    draws[:, 2] = wrap_angle(draws[:, 2])
    return draws


def localised(particles: np.ndarray, weights: np.ndarray, tolerance: float) -> bool:
    """The weighted cloud's position std (largest axis) is at most ``tolerance`` (m)."""
    w = weights / weights.sum()
    cov = weighted_pose_covariance(particles, w, weighted_pose_mean(particles, w))[:2, :2]
    return bool(np.linalg.eigvalsh(cov)[-1] <= tolerance ** 2)
