"""How alike a landmark's observation errors are from one scan to the next (docs/METHOD.md
"Noise learned online", serial correlation).

EM's R is the spread of one observation's error.  A real detector repeats much of its
error while it sees a landmark from nearly the same place (a tree trunk's centre
estimated from the same side, a reflector's extent), and the filter, which combines
observations as independent, then takes n of them for n independent ones.  The
correlation c of consecutive errors says how much less they inform: with AR(1) errors
the mean of n observations varies as R (1 + c) / (1 - c) / n
(``models.observation.information_noise``).

The statistic pairs each observation with the same landmark's observation in the scan
before, both as whitened residuals z = r / sqrt(diag cov r) of the posterior-mean innovations
after a pose correction from the scan alone (``pose_free``: the filter's pose error lasts too),
scaled by the square root of the noise model's precision factor (an outlier counts as in the
likelihood):

    c_j = (E[z_prev,j z_j] - m_j) / sqrt((E[z_prev,j^2] - m_j) (E[z_j^2] - m_j)),   j = range, bearing

m_j the landmark estimate's share of z's variance after the pose correction (``pose_free``).
"""
from __future__ import annotations

import math

import numpy as np

from .averages import mean


class PreviousInnovations:
    """Each landmark's last whitened innovation and the filter step it came from, by landmark id
    (ids are stable when the landmark table drops rows)."""

    def __init__(self) -> None:
        self.ids = np.zeros(0, dtype=np.int64)              # sorted
        self.steps = np.zeros(0, dtype=np.int64)
        self.z = np.zeros((0, 2))

    def pair(self, step: int, ids: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(previous whitened innovations (Q, 2), which of ``ids`` (P,) they pair with (P,)): the
        landmarks also seen at ``step - 1``; then remembers ``z`` (P, 2) as their latest."""
        ids = np.asarray(ids, dtype=np.int64)
        if not self.ids.size:
            self._insert(step, ids, z)
            return np.zeros((0, 2)), np.zeros(ids.shape, dtype=bool)
        at = np.minimum(np.searchsorted(self.ids, ids), self.ids.size - 1)
        known = self.ids[at] == ids
        consecutive = known & (self.steps[at] == step - 1)
        previous = self.z[at[consecutive]]
        self.steps[at[known]] = step
        self.z[at[known]] = z[known]
        self._insert(step, ids[~known], z[~known])
        return previous, consecutive

    def _insert(self, step: int, ids: np.ndarray, z: np.ndarray) -> None:
        if not ids.size:
            return
        ids, first = np.unique(ids, return_index=True)     # a landmark twice in one scan: once
        merged = np.concatenate([self.ids, ids])
        order = np.argsort(merged, kind="stable")
        self.ids = merged[order]
        self.steps = np.concatenate([self.steps, np.full(ids.size, step, dtype=np.int64)])[order]
        self.z = np.vstack([self.z, z[first]])[order]


def pose_free(nu: np.ndarray, S: np.ndarray, H_x: np.ndarray, D: np.ndarray | None = None):
    """The scan's innovations nu (P, 2) less what a pose correction explains, their covariances,
    and (with ``D``) what of those covariances the landmark estimates' errors make.

    The filter's pose error lasts from scan to scan and is common to the scan's observations:
    left in, it would read as correlated observation errors (and grow as the filter trusts
    the observations less).  The weighted least-squares correction dX = A^-1 sum H_x^T S^-1 nu,
    A = sum H_x^T S^-1 H_x, from this scan alone takes it out: r = M nu, M = I - H_x A^-1 H_x^T S^-1
    over the stacked scan, with covariance S - H_x A^-1 H_x^T.  A landmark's own error D_p
    (H Sigma_k H^T, P x (2, 2)) stays from scan to scan too: its part of r's covariance is the
    diagonal of M D M^T, returned as (P, 2) (else None).  Needs 2P > 3 (P >= 2).
    """
    P = nu.shape[0]
    S_inv = np.linalg.inv(S)
    HtSi = np.swapaxes(H_x, -1, -2) @ S_inv                                        # (P, 3, 2)
    A_inv = np.linalg.inv(np.einsum("pij,pjk->ik", HtSi, H_x))
    residual = nu - H_x @ (A_inv @ np.einsum("pij,pj->i", HtSi, nu))
    cov = S - H_x @ A_inv @ np.swapaxes(H_x, -1, -2)
    if D is None:
        return residual, cov, None
    M = np.eye(2 * P).reshape(2 * P, P, 2) - np.einsum("ia,ab,qbc->iqc", H_x.reshape(2 * P, 3), A_inv, HtSi)
    shared = np.einsum("iqa,qab,iqb->i", M, D, M).reshape(P, 2)        # D block diagonal: blockwise
    return residual, cov, shared


def whitened(nu: np.ndarray, S: np.ndarray, precision_weight: np.ndarray) -> np.ndarray:
    """z = nu / sqrt(diag S) x sqrt(precision_weight) (P, 2) from innovations nu (P, 2), their
    covariances S (P, 2, 2) and the noise model's precision factors (P,)."""
    scale = np.sqrt(np.maximum(precision_weight, 0.0))[:, None]
    return nu / np.sqrt(np.maximum(np.diagonal(S, axis1=-2, axis2=-1), 1e-300)) * scale


def pair_sample(previous: np.ndarray, current: np.ndarray, shared: np.ndarray) -> np.ndarray:
    """The step's mean of [z_prev z, z_prev^2, z^2] less ``shared`` per component (6,), from pairs
    (Q, 2), Q > 0: the moments of the observation errors' own parts.

    ``shared`` m (Q, 2): the part of z's variance that is the landmark estimate's error, which
    both innovations of a pair carry even when the observation errors are independent.
    """
    m = mean(shared, axis=0)
    return np.concatenate([mean(previous * current, axis=0) - m, mean(previous ** 2, axis=0) - m,
                           mean(current ** 2, axis=0) - m])


def serial_correlation(moments: np.ndarray, limit: float) -> tuple[float, float]:
    """(c_range, c_bearing) from the averaged [z_prev z, z_prev^2, z^2] (6,), within [0, limit]:
    a negative correlation (more information than independent errors) is not trusted."""
    values = []
    for j in range(2):
        denominator = math.sqrt(max(moments[2 + j] * moments[4 + j], 0.0))
        c = moments[j] / denominator if denominator > 0.0 else 0.0
        values.append(float(min(max(c, 0.0), limit)) if math.isfinite(c) else 0.0)
    return values[0], values[1]
