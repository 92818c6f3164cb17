"""Particle-filter primitives: weights, resampling, moments, Gaussian draws."""
from __future__ import annotations

import numpy as np

from ..models.angles import circular_mean, wrap_angle


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


def weighted_sum(weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    """sum_i w_i values[i] over the particle axis, as one BLAS matrix-vector product."""
    return (weights @ values.reshape(values.shape[0], -1)).reshape(values.shape[1:])


def weighted_outer(weights: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """sum_i w_i dev[i] dev[i]^T for 2-vectors dev (N, K, 2): (K, 2, 2)."""
    wd = dev * weights[:, None, None]
    out = np.empty(dev.shape[1:] + (2,))
    out[:, 0, 0] = (wd[..., 0] * dev[..., 0]).sum(axis=0)
    out[:, 1, 1] = (wd[..., 1] * dev[..., 1]).sum(axis=0)
    out[:, 0, 1] = out[:, 1, 0] = (wd[..., 0] * dev[..., 1]).sum(axis=0)
    return out


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


def weighted_pose_mean(poses: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean pose, circular mean for the yaw."""
    mean = np.empty(3)
    mean[:2] = weights @ poses[:, :2]
    mean[2] = circular_mean(poses[:, 2], weights)
    return mean


def weighted_pose_covariance(poses: np.ndarray, weights: np.ndarray, mean: np.ndarray,
                             spread: np.ndarray | None = None) -> np.ndarray:
    """Weighted covariance of poses around ``mean`` (yaw deviations wrapped).

    ``spread`` (N, 3, 3), when given, is each particle's own covariance (its
    predicted motion uncertainty) and is added as the mixture's within term.
    """
    dev = poses - mean
    dev[:, 2] = wrap_angle(dev[:, 2])
    cov = (dev * weights[:, None]).T @ dev
    if spread is not None:
        cov = cov + np.tensordot(weights, spread, axes=1)
    return 0.5 * (cov + cov.T)


def sample_gaussians(means: np.ndarray, covariances: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One draw from N(means[i], covariances[i]) per row, yaw wrapped."""
    chol = np.linalg.cholesky(covariances)
    draws = means + np.einsum("nij,nj->ni", chol, rng.standard_normal(means.shape))
    draws[:, 2] = wrap_angle(draws[:, 2])
    return draws


def symmetric_inverse_3x3(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and log-determinant of symmetric positive-definite (N, 3, 3) matrices
    by cofactors: for a hundred tiny matrices far cheaper than the LAPACK batch."""
    a, b, c = P[:, 0, 0], P[:, 0, 1], P[:, 0, 2]
    d, e, f = P[:, 1, 1], P[:, 1, 2], P[:, 2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c00 + b * c01 + c * c02
    inv = np.empty_like(P)
    inv[:, 0, 0], inv[:, 1, 1], inv[:, 2, 2] = c00, a * f - c * c, a * d - b * b
    inv[:, 0, 1] = inv[:, 1, 0] = c01
    inv[:, 0, 2] = inv[:, 2, 0] = c02
    inv[:, 1, 2] = inv[:, 2, 1] = b * c - a * e
    return inv / det[:, None, None], np.log(det)


def gaussian_transition_logpdf(targets: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """log m(x_j, x'_i) = log N(targets[i]; means[j], covariances[j]) for all pairs: (N_i, N_j).

    This is the (T) density of motion.py evaluated on every (i, j) pair, the
    O(N^2) part of the forward-only smoother.  The quadratic form is expanded
    by hand over the six distinct precision entries: elementwise (N_i, N_j)
    arrays are much faster than a generic einsum, and the yaw difference is
    wrapped exactly for any spread of the cloud.
    """
    precision, logdet = symmetric_inverse_3x3(covariances)
    dx = targets[:, None, 0] - means[None, :, 0]
    dy = targets[:, None, 1] - means[None, :, 1]
    dphi = targets[:, None, 2] - means[None, :, 2]
    dphi -= _TWO_PI * np.round(dphi / _TWO_PI)
    p = precision
    quad = (p[:, 0, 0] * dx * dx + p[:, 1, 1] * dy * dy + p[:, 2, 2] * dphi * dphi
            + 2.0 * (p[:, 0, 1] * dx * dy + p[:, 0, 2] * dx * dphi + p[:, 1, 2] * dy * dphi))
    return -0.5 * (quad + logdet[None, :]) - 1.5 * np.log(_TWO_PI)


_TWO_PI = 2.0 * np.pi
