"""Gaussians of 3-D poses: inverses of their covariances, and the transition density (T)
of models/motion.py on every pair of particles."""
from __future__ import annotations

import numpy as np


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
