"""The observation-noise statistics of the learner (docs/METHOD.md, "Noise learned online"),
and the M-step pieces that map their averages to the Student-t's dof and the mixture.

Observation statistics, per associated observation p with innovations
nu_ip = y_p - h(xi_i, thetabar_k) under the posterior particles (weights w_i):

    E_p   = sum_i w_i (sum_c r_ipc / s_c) nu_ip nu_ip^T (n_k - 1) / n_k             (E)

r_ipc the responsibility of mixture component c (scale s_c), n_k the landmark's
observation count.  The innovation is predictive (thetabar_k has not seen y_p
yet), so its second moment is R plus the map's uncertainty seen through h,
about R / (n_k - 1) for an estimate that averages n_k - 1 observations, so
R (1 + 1 / (n_k - 1)): the factor takes the map's share out, or R would absorb
the map's uncertainty (:func:`map_share`).
The pose's uncertainty needs no term: averaging over the posterior particles
is the E-step's expectation over the pose (mean outer product plus spread).

"""
from __future__ import annotations

import math
from functools import cached_property

import numpy as np
from scipy.optimize import brentq
from scipy.special import digamma

from ...config import ObservationNoiseConfig, SensorConfig
from ...noise_learning_config import NoiseLearningConfig
from ...models.observation import (component_precision_weight, inv_det_2x2, mahalanobis_d2, noise_loglik,
                                   student_t_weight)
from ..step import FilterStepData
from .averages import mean

def student_t_dof(statistic: float, low: float, high: float) -> float:
    """The dof maximising the expected complete-data log-likelihood of the Gamma(dof/2, dof/2)
    precision scales, given statistic = E[log tau - tau] (<= -1): the root of
    1 + log(dof/2) - psi(dof/2) + statistic = 0, within [low, high].

    log(v/2) - psi(v/2) falls from +inf to 0 as v grows, so the root is unique.
    """
    def score(log_dof: float) -> float:
        half = 0.5 * math.exp(log_dof)
        return 1.0 + math.log(half) - float(digamma(half)) + statistic

    lo, hi = math.log(low), math.log(high)
    if score(lo) <= 0.0:
        return low
    if score(hi) >= 0.0:
        return high                                  # the tails are no heavier than a Gaussian's
    return float(math.exp(brentq(score, lo, hi, xtol=1e-10)))


def map_share(n_obs: np.ndarray) -> np.ndarray:
    """(n_k - 1) / n_k (P,): the part of the innovation's second moment R (1 + 1/(n_k - 1)) that is R.

    A factor rather than subtracting R / (n_k - 1) with the current estimate of R: while
    that is still a wrong start (9x in variance, say) the difference can go negative
    for landmarks seen a few times, and the first, heavily weighted statistics would
    pin R to its floor.
    """
    m = np.maximum(np.asarray(n_obs, dtype=float) - 1.0, 1.0)
    return m / (m + 1.0)


def map_uncertainty(R: np.ndarray, n_obs: np.ndarray) -> np.ndarray:
    """H Sigma_k H^T ~ R / (n_k - 1) (P, 2, 2): the landmark's estimate averages its earlier
    observations, seen through h.

    Taken from the learned R rather than from the M-step's Sigma_k, which is
    built with the R in use: while that is still the wrong starting value
    (10 times too large, say), its map term would swamp the residuals.
    """
    return R / np.maximum(np.asarray(n_obs, dtype=float) - 1.0, 1.0)[:, None, None]


def pose_jacobian_from(H: np.ndarray, pose: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """dh/dX (P, 2, 3) from dh/dtheta (P, 2, 2) at base pose ``pose`` (observation.pose_jacobian
    without the landmarks): dh/dp = -dh/dtheta, the sensor lever arm, -1 on the bearing's yaw."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    lever = np.array([-s * sensor.offset_x - c * sensor.offset_y, c * sensor.offset_x - s * sensor.offset_y])
    J = np.empty(H.shape[:-1] + (3,))
    J[..., :2] = -H
    J[..., 2] = -(H @ lever)
    J[..., 1, 2] -= 1.0
    return J


def latent_variables(noise: ObservationNoiseConfig, nu: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """noise_loglik's latent variable (..., P, C) without its log-likelihood (the statistics do not
    use it), and the Student-t's d2 = nu^T S^-1 nu (..., P) for its tail statistic (else None).

    ``S`` (P, 2, 2) broadcasts against ``nu`` (..., P, 2): the Student-t's d2 then takes one
    inverse per observation, not one per particle (elementwise the same numbers); the other
    models get S at nu's shape, as noise_loglik always had it.
    """
    if noise.model == "student_t":
        d2 = mahalanobis_d2(nu, S)
        return student_t_weight(d2, noise.dof)[..., None], d2
    if noise.model == "gaussian":
        return np.ones(nu.shape[:-1] + (1,)), None           # noise_loglik's latent, without its likelihood
    return noise_loglik(noise, nu, np.broadcast_to(S, nu.shape + (2,)))[1], None



class UsedObservations:
    """The step's observations that inform the noise (``use``) and what the statistics take
    of them, computed once: ranges (P,), counts n_k (P,), innovations nu (N, P, 2), Jacobians
    H (N, P, 2, 2), their R (P, 2, 2) under the current estimate ``noise`` and the map term
    R / (n_k - 1) (P, 2, 2); ``scan`` their posterior means at the mean ``pose``."""

    def __init__(self, data: FilterStepData, n_obs: np.ndarray, use: np.ndarray, R: np.ndarray,
                 pose: np.ndarray, sensor: SensorConfig, noise: ObservationNoiseConfig) -> None:
        self.ranges, self.n_obs = data.y[use, 0], n_obs[use]
        self.nu, self.H = data.nu[:, use], data.H[:, use]
        self.R = R
        self.map_term = map_uncertainty(R, self.n_obs)
        self._mean_of = (data.weights, pose, sensor, noise)

    @cached_property
    def S(self) -> np.ndarray:
        """R + R / (n_k - 1) (P, 2, 2): the innovations' covariance, made once for the statistics."""
        return self.R + self.map_term

    @cached_property
    def scan_terms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(H_x (P, 2, 3), posterior mean innovation (P, 2), noise covariance (P, 2, 2)) of the scan for
        the window's statistics, made once: the learned R times each observation's variance factor
        (an outlier's wider) plus the map term H Sigma H^T."""
        nu, H_x, _ = self.scan
        return H_x, nu, self.R * self.variance_factor[:, None, None] + self.map_term

    @cached_property
    def scan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(posterior-mean innovations nubar (P, 2), pose Jacobians H_x (P, 2, 3) at the mean pose,
        the noise model's precision factors at nubar (P,)): shared by the motion and serial statistics."""
        w, pose, sensor, noise = self._mean_of
        nu, latent = self._mean_latent
        H = np.einsum("n,npij->pij", w, self.H)
        return nu, pose_jacobian_from(H, pose, sensor), component_precision_weight(noise, latent)

    @cached_property
    def _mean_latent(self) -> tuple[np.ndarray, np.ndarray]:
        """(posterior-mean innovations nubar (P, 2), the noise model's latent variables at them (P, C))."""
        w, _, _, noise = self._mean_of
        nu = np.einsum("n,npi->pi", w, self.nu)
        return nu, latent_variables(noise, nu, self.S)[0]

    @cached_property
    def variance_factor(self) -> np.ndarray:
        """The factor on R of each observation's noise variance (P,), for the motion statistic's
        K: under the mixture the scale of the likelier component (exactly 1 for an inlier),
        otherwise 1 / the precision factor.  Not the precision factor's inverse under the
        mixture: an inlier with some responsibility for the outlier component would count
        more variance than it has, and the statistic, which subtracts K, would learn a
        motion scale 5 % low (docs/RESULTS.md)."""
        noise = self._mean_of[3]
        if noise.model != "mixture":
            return 1.0 / self.scan[2]
        return np.asarray(noise.mixture_scales, dtype=float)[np.argmax(self._mean_latent[1], axis=-1)]



def observation_statistics(noise: ObservationNoiseConfig, weights: np.ndarray, used: UsedObservations | None,
                           tails: bool = True):
    """(the step's mean of [E_bb, rho term, tail statistics], ranges, E_rr), from (E), over the
    ``used`` observations (landmarks seen often enough, the configured R), with the latent
    variables under ``noise`` (None when nothing is used or a statistic is not finite).

    ``tails`` False leaves the tail statistics out (the learner learns neither the mixture nor
    the dof): they are most of the statistics' cost and their M-step would not run.
    """
    if used is None:
        return None
    ranges, nu, R, w = used.ranges, used.nu, used.R, weights
    latent, d2 = latent_variables(noise, nu, used.S)                             # (N, P, C)
    outer = nu[..., :, None] * nu[..., None, :] * map_share(used.n_obs)[:, None, None]
    E = np.einsum("n,np,npij->pij", w, component_precision_weight(noise, latent), outer)  # (E), (P, 2, 2)
    a, b = noise.sigma_range, noise.range_growth
    parts = [[mean(E[:, 1, 1]), mean(a * E[:, 0, 1] / (a + b * ranges))]]     # rho scales with sigma_r(r)
    if tails:
        parts.append(tail_statistics(noise, w, latent, outer, R, d2))
    sample = np.concatenate(parts)
    if not (np.isfinite(sample).all() and np.isfinite(E[:, 0, 0]).all()):
        return None
    return sample, ranges, E[:, 0, 0]


def tail_statistics(noise: ObservationNoiseConfig, w: np.ndarray, latent: np.ndarray, outer: np.ndarray,
                    R: np.ndarray, d2: np.ndarray | None) -> np.ndarray:
    """The statistics of the tails' parameters, averaged over the scan's observations.

    Mixture: mean responsibilities r_c and r_c q, q = tr(R^-1 outer) / 2 (weights and
    outlier scales).  Student-t: E[log tau - tau | nu] with tau | nu ~ Gamma((dof + 2)/2,
    (dof + d2)/2), so E[log tau] = psi((dof + 2)/2) - log((dof + d2)/2) (the dof), d2 (N, P)
    the innovations' nu^T S^-1 nu.
    """
    if noise.model == "student_t":
        log_tau = digamma(0.5 * noise.dof + 1.0) - np.log(0.5 * (noise.dof + d2))
        return np.array([mean(np.einsum("n,np->p", w, log_tau - latent[..., 0]))])
    R_inv, _ = inv_det_2x2(R)
    q = 0.5 * np.einsum("pij,npji->np", R_inv, outer)                             # tr(R^-1 outer) / 2
    return np.concatenate([mean(np.einsum("n,npc->pc", w, latent), axis=0),
                           mean(np.einsum("n,npc,np->pc", w, latent, q), axis=0)])


def mixture_m_step(stats: np.ndarray, scales_now: tuple, settings: NoiseLearningConfig) -> dict:
    """Weights = mean responsibilities; outlier scales = E[r_c q] / E[r_c] (component 0 keeps scale 1),
    ``scales_now`` the current scales (an outlier component without responsibility keeps its own)."""
    s = settings
    c = stats.size // 2
    resp, q = stats[:c], stats[c:]
    outlier_w = np.clip(resp[1:], *s.mixture_weight_limits)
    outlier_w *= min(1.0, 0.5 / max(outlier_w.sum(), 1e-300))      # the inlier keeps at least half
    scales = np.asarray(scales_now, dtype=float).copy()
    seen = resp[1:] > 1e-9
    scales[1:][seen] = np.clip(q[1:][seen] / resp[1:][seen], *s.mixture_scale_limits)
    weights = np.concatenate([[1.0 - outlier_w.sum()], outlier_w])
    return {"mixture_weights": tuple(float(v) for v in weights / math.fsum(weights)),
            "mixture_scales": (1.0,) + tuple(float(v) for v in scales[1:])}
