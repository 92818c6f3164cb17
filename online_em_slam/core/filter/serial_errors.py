"""Serially correlated observation errors in the particles' likelihood (AR(1), exact).

A landmark's error e_t = C e_{t-1} + w_t, C = diag(c_range, c_bearing), w_t ~ N(0, Q) with
Q = R - C R C (stationary spread R): given the particle's last innovation of the same
landmark at the step before, y_t's density is that of the quasi-difference
nu_t - C nu_{t-1} under Q.  The first observation of a run of views has the marginal R.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import ObservationNoiseConfig
from ..models.angles import wrap_angle
from ..models.observation import noise_loglik


class LastInnovations:
    """Each particle's innovations (N, P, 2) of the landmarks ``ids`` (P,) seen at ``step``."""

    def __init__(self) -> None:
        self.step = -2
        self.ids = np.zeros(0, dtype=np.int64)
        self.nu = None

    def store(self, step: int, ids: np.ndarray, nu: np.ndarray) -> None:
        self.step, self.ids, self.nu = step, np.asarray(ids, dtype=np.int64), nu

    def weigh(self, terms, step: int, ids: np.ndarray, R: np.ndarray, ancestors: np.ndarray,
              noise: ObservationNoiseConfig, weighting: np.ndarray) -> None:
        """``terms.log_likelihood`` under AR(1) errors with ``noise``'s serial correlation (when it
        has one); then remembers the step's innovations ``terms.nu``."""
        if any(noise.serial_correlation):
            terms.log_likelihood = ar1_log_likelihood(self, step, ids, terms.nu, R, ancestors, noise, weighting)
        self.store(step, ids, terms.nu)

    def quasi_differenced(self, step: int, ids: np.ndarray, nu: np.ndarray, ancestors: np.ndarray,
                          c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(nu - C nu_prev of each particle's ancestor (N, P, 2), which observations had one (P,))."""
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
        out[:, matched] = nu[:, matched] - c * prev
        out[..., 1] = wrap_angle(out[..., 1])
        return out, matched


def innovation_noise(R: np.ndarray, c: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """Q = R - C R C for the observations with a predecessor (P, 2, 2), R for the rest."""
    Q = R * (1.0 - np.outer(c, c))
    return np.where(matched[:, None, None], Q, R)


def ar1_log_likelihood(last: LastInnovations, step: int, ids: np.ndarray, nu: np.ndarray, R: np.ndarray,
                       ancestors: np.ndarray, noise: ObservationNoiseConfig, weighting: np.ndarray) -> np.ndarray:
    """Each particle's log-likelihood (N,) of the scan's innovations ``nu`` (N, P, 2) of landmarks
    ``ids`` (P,) with one observation's spread ``R`` (P, 2, 2), under ``noise``'s law and its
    serial correlation, summed over the landmarks that weight (``weighting`` (P,))."""
    c = np.asarray(noise.serial_correlation, dtype=float)
    nu_q, matched = last.quasi_differenced(step, ids, nu, ancestors, c)
    loglik, _ = noise_loglik(replace(noise, serial_correlation=(0.0, 0.0)), nu_q, innovation_noise(R, c, matched))
    return np.where(weighting[None, :], loglik, 0.0).sum(axis=1)
