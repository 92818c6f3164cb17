"""Weighted moments over particles: sums, outer products, the mean pose and its covariance.

Below the filter and the EM pieces, which both take moments of the weighted particles.
"""
from __future__ import annotations

import numpy as np

from .models.angles import circular_mean, wrap_angle


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
