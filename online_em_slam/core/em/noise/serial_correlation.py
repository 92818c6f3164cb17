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

A camera repeats its error while its view of the landmark stays: the correlation of two
sightings falls with the viewpoint's change v between them (the sensor's travel plus
noise.serial_turn_length per radian turned), c(v) = c0 exp(-v / l).  With ``serial_length``
learned the statistic pairs each observation with its landmark's previous sighting, however
many scans ago, bins the pairs by v (:class:`ViewpointPairs`) and fits (c0, l) per component to
the bins' correlations (:func:`decay_fit`); one c would be the mix of viewpoint changes the run
happens to drive.
"""
from __future__ import annotations

import math

import numpy as np

from ...mapping.last_sighting import LastSightings
from ...models.observation import viewpoint_change
from .averages import StochasticAverage, batch_step_sizes, mean
from .range_fit import group_sums

# Bins of the viewpoint change v (m) between a landmark's consecutive sightings; the last is
# open.  Fine where a camera's correlation falls (0.9 within 2 cm, 0.6 at 10-20 cm, none at 1 m).
VIEWPOINT_EDGES = np.array([0.01, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6])
# The decay lengths l (m) the fit chooses among.
DECAY_LENGTHS = np.geomspace(0.01, 10.0, 61)


class SerialStatistic:
    """The serial correlation's statistic: pairs of consecutive scans (one c), or with ``decay``
    pairs of consecutive sightings binned by the viewpoint change between them (c0, l)."""

    def __init__(self, alpha: float, decay: bool, turn_length: float) -> None:
        self.average = StochasticAverage(alpha)            # consecutive innovations' moments
        self.previous = PreviousInnovations()
        self.pairs = ViewpointPairs(turn_length, alpha) if decay else None

    def update(self, step: int, ids: np.ndarray, z: np.ndarray, share: np.ndarray, sensor_pose: np.ndarray) -> None:
        """One scan's whitened pose-free innovations ``z`` (P, 2) of landmarks ``ids`` (P,) seen from
        ``sensor_pose`` (3,), ``share`` (P, 2) the landmark estimates' part of their variance."""
        if self.pairs is not None:
            self.pairs.blend(ids, z, share, sensor_pose)
            return
        previous, paired = self.previous.pair(step, ids, z)
        if previous.shape[0] and np.isfinite(previous).all() and np.isfinite(z[paired]).all():
            self.average.blend(pair_sample(previous, z[paired], share[paired]), previous.shape[0])

    def values(self, limit: float) -> dict:
        """The M-step's serial_correlation (and with ``decay`` serial_length); {} before any pair."""
        if self.pairs is not None:
            fit = self.pairs.fit(limit)
            return {} if fit is None else {"serial_correlation": fit[0], "serial_length": fit[1]}
        if self.average.value is None:
            return {}
        return {"serial_correlation": serial_correlation(self.average.value, limit)}


class ViewpointPairs:
    """Each landmark's last whitened innovation and the sensor pose it was seen from, and per bin
    of the viewpoint change v between a landmark's consecutive sightings the stochastic average
    of [v, z_prev z - m, z_prev^2 - m, z^2 - m] (7,) (:func:`pair_sample`'s, per pair)."""

    def __init__(self, turn_length: float, alpha: float) -> None:
        self.turn_length, self.alpha = turn_length, alpha
        self.last = LastSightings(5)                         # z (2), sensor pose (3)
        self.counts = np.zeros(VIEWPOINT_EDGES.size + 1, dtype=np.int64)
        self.values = np.zeros((VIEWPOINT_EDGES.size + 1, 7))

    def blend(self, ids: np.ndarray, z: np.ndarray, share: np.ndarray, sensor_pose: np.ndarray) -> None:
        """Pair the scan's ``z`` (P, 2) with its landmarks' previous sightings; blend the pairs."""
        previous = self.last.recall(ids)
        finite = np.isfinite(z).all(axis=1)
        self.last.record(ids[finite], np.hstack([z, np.broadcast_to(sensor_pose, (len(ids), 3))])[finite])
        paired = finite & ~np.isnan(previous[:, 0])
        if not paired.any():
            return
        v = viewpoint_change(previous[paired, 2:], sensor_pose, self.turn_length)
        before, now, m = previous[paired, :2], z[paired], share[paired]
        sample = np.hstack([v[:, None], before * now - m, before ** 2 - m, now ** 2 - m])       # (Q, 7)
        index = np.searchsorted(VIEWPOINT_EDGES, v)
        order = np.argsort(index, kind="stable")
        bins, sizes, sums = group_sums(index[order], sample[order].T)
        means = sums / sizes[:, None]
        counts = self.counts[bins]
        gamma = batch_step_sizes(counts, sizes, self.alpha)
        old = self.values[bins]
        self.values[bins] = np.where((counts == 0)[:, None], means, old + gamma[:, None] * (means - old))
        self.counts[bins] = counts + sizes

    def fit(self, limit: float) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """(c0, l) per component (:func:`decay_fit`); None before two bins say anything.

        A bin weighs as the inverse variance of a correlation from its pairs, n - 3 by Fisher's
        z (n = count^alpha, the average's effective sample size): a bin of three pairs or fewer
        says nothing.  Unweighted, ten pairs in four bins once gave c0 0.95 at l = 10 m, every
        observation counted as a fortieth, and the filter lost its way (MRCLAM D9 R4)."""
        weights = np.maximum(self.counts.astype(float) ** self.alpha - 3.0, 0.0)
        full = weights > 0.0
        if full.sum() < 2:
            return None
        return decay_fit(weights[full], self.values[full, 0], self.values[full, 1:], limit)


def decay_fit(weights: np.ndarray, v: np.ndarray, moments: np.ndarray,
              limit: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """((c0_range, c0_bearing), (l_range, l_bearing)) of c(v) = c0 exp(-v / l) by weighted least
    squares against the bins' correlations c_k = M_k / sqrt(P_k C_k) at their mean viewpoint
    changes ``v`` (K,), ``moments`` (K, 6) their averaged [z_prev z, z_prev^2, z^2] per component,
    ``weights`` (K,) their inverse variances.  For each l of DECAY_LENGTHS c0 is closed form (within [0,
    ``limit``]); the l of the smallest weighted squared error wins."""
    g = np.exp(-v[None, :] / DECAY_LENGTHS[:, None])                                  # (L, K)
    c0s, lengths = [], []
    for j in range(2):
        denominator = np.sqrt(np.maximum(moments[:, 2 + j] * moments[:, 4 + j], 0.0))
        usable = denominator > 0.0
        c = np.where(usable, moments[:, j] / np.where(usable, denominator, 1.0), 0.0)
        w = np.where(usable, weights, 0.0)
        c0 = np.clip((g * (w * c)).sum(axis=1) / np.maximum((g * g * w).sum(axis=1), 1e-300), 0.0, limit)
        error = (w * (c[None, :] - c0[:, None] * g) ** 2).sum(axis=1)
        best = int(np.argmin(error))
        c0s.append(float(c0[best]))
        lengths.append(float(DECAY_LENGTHS[best]))
    return (c0s[0], c0s[1]), (lengths[0], lengths[1])


class PreviousInnovations:
    """Each landmark's last whitened innovation and the filter step it came from, by landmark id
    (ids are stable when the landmark table drops rows)."""

    def __init__(self) -> None:
        self.last = LastSightings(3)                         # step, z (2)

    def pair(self, step: int, ids: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(previous whitened innovations (Q, 2), which of ``ids`` (P,) they pair with (P,)): the
        landmarks also seen at ``step - 1``; then remembers ``z`` (P, 2) as their latest."""
        previous = self.last.recall(ids)
        consecutive = previous[:, 0] == step - 1
        self.last.record(ids, np.hstack([np.full((len(ids), 1), float(step)), z]))
        return previous[consecutive, 1:], consecutive


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
