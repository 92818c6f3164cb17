"""Serially correlated observation errors in the particles' likelihood.

Each observation weighs as (1 - c) / (1 + c) of an independent one (R x (1 + c) / (1 - c)),
with one c for all, or with its own c = c0 exp(-v / l) when the correlation decays with the
viewpoint's change v since the landmark's previous sighting (:class:`SerialWeighing`).

AR(1), exact (``filter.serial_likelihood: ar1``): a landmark's error e_t = C e_{t-1} + w_t,
C = diag(c_range, c_bearing), w_t ~ N(0, Q) with Q = R - C R C (stationary spread R): given the
particle's last innovation of the same landmark at the step before, y_t's density is that of
the quasi-difference nu_t - C nu_{t-1} under Q.  The first observation of a run of views has
the marginal R; with a decaying correlation, a landmark seen again after a gap weighs as above.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import ObservationNoiseConfig
from ..mapping.last_sighting import LastSightings
from ..models.angles import wrap_angle
from ..models.observation import (noise_loglik, observation_correlation, serial_decays, serially_weighed,
                                  viewpoint_change)
from ..types import Observations
from ..weighted import weighted_pose_mean
from .observation_terms import scan_noise


class SerialWeighing:
    """R of a scan's observations under serially correlated errors, and the particles' last
    innovations for the AR(1) likelihood.  ``viewpoints``: keep the sensor pose each landmark
    was last seen from (the correlation decays, or may once learned)."""

    def __init__(self, viewpoints: bool) -> None:
        self.last = LastInnovations()
        self.viewpoints = LastSightings(3) if viewpoints else None

    def scan_noise(self, in_use: ObservationNoiseConfig, weighed: ObservationNoiseConfig, obs: Observations,
                   idx: np.ndarray, ids: np.ndarray, sensor: np.ndarray,
                   weights: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(R (P, 2, 2) the likelihood and the M-step weigh the observations ``idx`` of landmarks
        ``ids`` (P,) with, seen from the particles' sensor poses ``sensor`` (N, 3) of ``weights``
        (N,); each observation's c (P, 2), or None when one c holds for all and R is that of
        ``weighed``, the information_noise of ``in_use``)."""
        v = None
        if self.viewpoints is not None:
            sensor_pose = weighted_pose_mean(sensor, weights)
            v = viewpoint_change(self.viewpoints.recall(ids), sensor_pose, in_use.serial_turn_length)
            self.viewpoints.record(ids, np.broadcast_to(sensor_pose, (len(ids), 3)))
        if v is None or not serial_decays(in_use):
            return scan_noise(weighed, obs, idx), None
        c = observation_correlation(in_use, v)
        return serially_weighed(scan_noise(in_use, obs, idx), c), c


class LastInnovations:
    """Each particle's innovations (N, P, 2) of the landmarks ``ids`` (P,) seen at ``step``."""

    def __init__(self) -> None:
        self.step = -2
        self.ids = np.zeros(0, dtype=np.int64)
        self.nu = None

    def store(self, step: int, ids: np.ndarray, nu: np.ndarray) -> None:
        self.step, self.ids, self.nu = step, np.asarray(ids, dtype=np.int64), nu

    def weigh(self, terms, step: int, ids: np.ndarray, R: np.ndarray, ancestors: np.ndarray,
              noise: ObservationNoiseConfig, weighting: np.ndarray, c: np.ndarray | None = None) -> None:
        """``terms.log_likelihood`` under AR(1) errors with ``noise``'s serial correlation (when it
        has one), or each observation's own ``c`` (P, 2) (those without a predecessor then weigh
        under ``terms.R``); then remembers the step's innovations ``terms.nu``."""
        if any(noise.serial_correlation):
            terms.log_likelihood = ar1_log_likelihood(self, step, ids, terms.nu, R, ancestors, noise, weighting,
                                                      c, None if c is None else terms.R)
        self.store(step, ids, terms.nu)

    def quasi_differenced(self, step: int, ids: np.ndarray, nu: np.ndarray, ancestors: np.ndarray,
                          c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(nu - C nu_prev of each particle's ancestor (N, P, 2), which observations had one (P,));
        ``c`` (2,) or each observation's (P, 2)."""
        ids = np.asarray(ids, dtype=np.int64)
        matched = np.zeros(ids.shape, dtype=bool)
        if self.nu is None or self.step != step - 1 or not ids.size or not self.ids.size:
            return nu, matched
        order = np.argsort(self.ids, kind="stable")
        at = np.minimum(np.searchsorted(self.ids[order], ids), self.ids.size - 1)
        source = order[at]
        matched = self.ids[source] == ids
        out = nu.copy()
        prev = self.nu[ancestors][:, source[matched]]                                # (N, Q, 2)
        out[:, matched] = nu[:, matched] - (c if c.ndim == 1 else c[matched]) * prev
        out[..., 1] = wrap_angle(out[..., 1])
        return out, matched


def innovation_noise(R: np.ndarray, c: np.ndarray, matched: np.ndarray,
                     unmatched: np.ndarray | None = None) -> np.ndarray:
    """Q = R - C R C for the observations with a predecessor (P, 2, 2), ``unmatched`` (default R)
    for the rest; ``c`` (2,) or each observation's (P, 2)."""
    Q = R * (1.0 - c[..., :, None] * c[..., None, :])
    # With c_range != c_bearing and a strong range-bearing covariance R - C R C is not positive
    # definite (no AR(1) has that R): the cross term kept within its bound, the diagonal exact.
    bound = 0.999 * np.sqrt(Q[..., 0, 0] * Q[..., 1, 1])
    Q[..., 0, 1] = Q[..., 1, 0] = np.clip(Q[..., 0, 1], -bound, bound)
    return np.where(matched[:, None, None], Q, R if unmatched is None else unmatched)


def ar1_log_likelihood(last: LastInnovations, step: int, ids: np.ndarray, nu: np.ndarray, R: np.ndarray,
                       ancestors: np.ndarray, noise: ObservationNoiseConfig, weighting: np.ndarray,
                       c: np.ndarray | None = None, unmatched: np.ndarray | None = None) -> np.ndarray:
    """Each particle's log-likelihood (N,) of the scan's innovations ``nu`` (N, P, 2) of landmarks
    ``ids`` (P,) with one observation's spread ``R`` (P, 2, 2), under ``noise``'s law and its
    serial correlation (or each observation's ``c`` (P, 2), those without a predecessor under
    ``unmatched``), summed over the landmarks that weight (``weighting`` (P,))."""
    c = np.asarray(noise.serial_correlation, dtype=float) if c is None else c
    nu_q, matched = last.quasi_differenced(step, ids, nu, ancestors, c)
    loglik, _ = noise_loglik(replace(noise, serial_correlation=(0.0, 0.0)), nu_q,
                             innovation_noise(R, c, matched, unmatched))
    return np.where(weighting[None, :], loglik, 0.0).sum(axis=1)
