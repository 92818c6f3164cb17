"""FastSLAM 2.0 baseline (Montemerlo et al. 2003), vectorised over particles.

Each particle i carries a pose and, per landmark k, a 2x2 EKF (mu_ik, Sigma_ik).
Between scans the pose is not sampled: each particle keeps the Gaussian
prediction N(m_i, C_i) compounded over the control steps (EKF moments of the
motion model, as in motion.py (T)).  At a scan with associated observations
y_j -> landmark k_j (loop over the few observations, arrays over particles):

  proposal (sequential Kalman fusion of the motion prior and each observation):
    Q_j = R_j + Hl Sigma_k Hl^T,      L_j = Hx C Hx^T + Q_j,
    Kx = C Hx^T L_j^-1,   m <- m + Kx (y_j - h(m, mu_k)),   C <- C - Kx L_j Kx^T   (F1)
  importance weight (the proposal's normaliser, product of predictive terms):
    w_i <- w_i prod_j N(y_j; h(m, mu_k), L_j)                                    (F2)
  then x_i ~ N(m_i, C_i) and each landmark EKF is updated at the sampled pose:
    S = Hl Sigma Hl^T + R,  K = Sigma Hl^T S^-1,  mu += K nu,  Sigma = (I - K Hl) Sigma  (F3)
  new landmarks: mu = g(x_i, y), Sigma = G_z R G_z^T                              (F4)
Systematic resampling when ESS < resample_threshold * N.

Unknown ids are associated with the particle-weighted moment-matched
prediction (z_hat_k = sum_i w_i z_hat_ik, S_k = sum_i w_i (S_ik + d d^T) + R),
so all methods share :func:`online_em_slam.core.filter.association.associate`.
"""
from __future__ import annotations

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.filter.association import Gates
from ..core.models.motion import propagate, step_jitter
from ..core.models.observation import (inv_det_2x2, innovation, inverse_observation, landmark_jacobian,
                                noise_loglik, pose_jacobian, predict_observation, sensor_poses)
from ..core.filter.particles import effective_sample_size, normalize_log_weights, sample_gaussians, systematic_resample
from ..core.weighted import weighted_pose_covariance, weighted_pose_mean
from ..core.types import LandmarkMap, Observations, PoseEstimate, StepReport
from ._common import BaselineFilter, LandmarkBook, inverse_observation_jacobians, plan_associations


def _t(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def symmetrize(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + _t(A))


def observation_terms(means: np.ndarray, mu: np.ndarray, sigma: np.ndarray, sensor
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per particle: h(m, mu), Hx = dh/dX, Hl = dh/dtheta and Hl Sigma Hl^T (broadcast over leading axes)."""
    sp = sensor_poses(means, sensor)
    z_hat = predict_observation(sp, mu)
    Hx = pose_jacobian(means, mu, sensor)
    Hl = landmark_jacobian(sp, mu)
    return z_hat, Hx, Hl, Hl @ sigma @ _t(Hl)


def proposal_step(mean: np.ndarray, cov: np.ndarray, z: np.ndarray, R: np.ndarray, mu: np.ndarray,
                  sigma: np.ndarray, sensor, noise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F1) and the log of the (F2) factor for one observation, all particles at once."""
    z_hat, Hx, _, HSH = observation_terms(mean, mu, sigma, sensor)
    L = symmetrize(Hx @ cov @ _t(Hx) + HSH + R)
    nu = innovation(np.broadcast_to(z, z_hat.shape).copy(), z_hat)
    loglik, _ = noise_loglik(noise, nu, L)
    L_inv, _ = inv_det_2x2(L)
    gain = cov @ _t(Hx) @ L_inv                                     # (N, 3, 2)
    mean = mean + np.einsum("nij,nj->ni", gain, nu)
    mean[:, 2] = wrap_angle(mean[:, 2])
    cov = symmetrize(cov - gain @ L @ _t(gain))
    return mean, cov, loglik


def landmark_update(poses: np.ndarray, z: np.ndarray, R: np.ndarray, mu: np.ndarray, sigma: np.ndarray,
                    sensor) -> tuple[np.ndarray, np.ndarray]:
    """(F3) for one observation of one landmark in every particle (Joseph form)."""
    sp = sensor_poses(poses, sensor)
    z_hat = predict_observation(sp, mu)
    Hl = landmark_jacobian(sp, mu)
    S = Hl @ sigma @ _t(Hl) + R
    S_inv, _ = inv_det_2x2(S)
    gain = sigma @ _t(Hl) @ S_inv
    nu = innovation(np.broadcast_to(z, z_hat.shape).copy(), z_hat)
    mu = mu + np.einsum("nij,nj->ni", gain, nu)
    A = np.eye(2) - gain @ Hl
    sigma = A @ sigma @ _t(A) + gain @ R @ _t(gain)
    return mu, symmetrize(sigma)


def moment_matched_prediction(weights: np.ndarray, means: np.ndarray, covs: np.ndarray,
                              mu: np.ndarray, sigma: np.ndarray, sensor) -> tuple[np.ndarray, np.ndarray]:
    """Particle mixture of the predicted measurements collapsed to one Gaussian per landmark:
    z_hat_k = sum_i w_i z_ik (circular mean for the bearing),
    S0_k = sum_i w_i (Hx C_i Hx^T + Hl Sigma_ik Hl^T + d_ik d_ik^T), d_ik = z_ik - z_hat_k."""
    z_ik, Hx, _, HSH = observation_terms(means[:, None, :], mu, sigma, sensor)     # (N, K, ...)
    z_hat = np.empty(z_ik.shape[1:])
    z_hat[:, 0] = weights @ z_ik[..., 0]
    z_hat[:, 1] = np.arctan2(weights @ np.sin(z_ik[..., 1]), weights @ np.cos(z_ik[..., 1]))
    d = innovation(z_ik, np.broadcast_to(z_hat, z_ik.shape))
    within = Hx @ covs[:, None, :, :] @ _t(Hx) + HSH + d[..., :, None] * d[..., None, :]
    return z_hat, np.einsum("n,nkij->kij", weights, within)


def sample_pose(means: np.ndarray, covs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """x_i ~ N(m_i, C_i); falls back to an eigen-decomposition (negative eigenvalues
    clipped) when round-off made some C_i indefinite, so sampling never raises."""
    try:
        return sample_gaussians(means, covs + 1e-12 * np.eye(3), rng)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(symmetrize(covs))
        root = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]
        draws = means + np.einsum("nij,nj->ni", root, rng.standard_normal(means.shape))
        draws[:, 2] = wrap_angle(draws[:, 2])
        return draws


class FastSlam2(BaselineFilter):
    """FastSLAM 2.0 with the public API of :class:`OnlineEMSlam` (docs/API.md)."""

    def _reset_state(self, initial_pose: np.ndarray) -> None:
        filt = self.config.filter
        n = int(filt.num_particles)
        self._rng = np.random.default_rng(filt.seed)
        std = np.asarray(filt.initial_pose_std, dtype=float)
        self._means = initial_pose[None, :] + self._rng.standard_normal((n, 3)) * std
        self._covs = np.zeros((n, 3, 3))
        self._weights = np.full(n, 1.0 / n)
        self._mu = np.zeros((n, 0, 2))
        self._sigma = np.zeros((n, 0, 2, 2))
        self._book = LandmarkBook()
        self._gates = Gates.from_config(self.config.association, self.config.noise)
        self.last_ess = float(n)

    def _predict(self, control: np.ndarray, dt: float) -> None:
        """Compound the motion Gaussian: m <- f(m, u), C <- F C F^T + G Q G^T."""
        mean, F, Q = propagate(self.config.motion, self._means, control, dt)
        mean[:, 2] = wrap_angle(mean[:, 2])
        self._means = mean
        self._covs = F @ self._covs @ _t(F) + Q

    def _update(self, observations: Observations, R: np.ndarray, report: StepReport) -> None:
        cfg, sensor = self.config, self.config.sensor
        z = np.stack([observations.ranges, observations.bearings], axis=1)
        cov = self._covs + step_jitter(cfg.motion)
        upd_obs, upd_slots, new_obs, new_ids = plan_associations(
            observations, self._book,
            lambda: moment_matched_prediction(self._weights, self._means, cov, self._mu, self._sigma, sensor),
            R, self._gates, report, self._count)

        mean, log_w = self._means, np.log(self._weights)
        for o, k in zip(upd_obs, upd_slots):
            mean, cov, loglik = proposal_step(mean, cov, z[o], R[o], self._mu[:, k], self._sigma[:, k],
                                              sensor, cfg.noise)
            log_w = log_w + loglik
        poses = sample_pose(mean, cov, self._rng)
        self._weights, _ = normalize_log_weights(log_w)

        for o, k in zip(upd_obs, upd_slots):
            self._mu[:, k], self._sigma[:, k] = landmark_update(poses, z[o], R[o], self._mu[:, k],
                                                                self._sigma[:, k], sensor)
        np.add.at(self._book.n_obs, upd_slots, 1)
        report.n_associated = int(upd_obs.size)
        self._create(poses, z, R, new_obs, new_ids, report)
        self._means, self._covs = poses, np.zeros_like(self._covs)
        self._prune(report)

        report.ess = self.last_ess = effective_sample_size(self._weights)
        if report.ess < cfg.filter.resample_threshold * len(self._weights):
            ancestors = systematic_resample(self._weights, self._rng)
            self._means, self._covs = self._means[ancestors], self._covs[ancestors]
            self._mu, self._sigma = self._mu[ancestors], self._sigma[ancestors]
            self._weights = np.full(len(ancestors), 1.0 / len(ancestors))

    def _create(self, poses, z, R, new_obs, new_ids, report) -> None:
        """(F4) for every particle at its sampled pose."""
        if not len(new_obs):
            return
        room = self.config.association.max_landmarks - len(self._book)
        if len(new_obs) > room:
            self._count(report, "map_full", len(new_obs) - max(room, 0))
            new_obs, new_ids = new_obs[:max(room, 0)], new_ids[:max(room, 0)]
        sp = sensor_poses(poses, self.config.sensor)[:, None, :]
        mu = inverse_observation(sp, z[new_obs][None, :, :])                       # (N, n, 2)
        _, Gz = inverse_observation_jacobians(poses[:, None, :], z[new_obs][None, :, :], self.config.sensor)
        sigma = Gz @ R[new_obs][None] @ _t(Gz)
        self._mu = np.concatenate([self._mu, mu], axis=1)
        self._sigma = np.concatenate([self._sigma, symmetrize(sigma)], axis=1)
        for landmark_id in new_ids:
            self._book.add(landmark_id, self._scan_count)
        report.n_created += len(new_obs)

    def _prune(self, report: StepReport) -> None:
        assoc = self.config.association
        stale = self._book.stale(self._scan_count, assoc.confirm_observations, assoc.tentative_timeout)
        if stale.any():
            self._mu, self._sigma = self._mu[:, ~stale], self._sigma[:, ~stale]
            self._book.keep(~stale)
            report.n_pruned = int(stale.sum())

    # -- outputs -------------------------------------------------------------------
    def pose(self) -> PoseEstimate:
        """Weighted particle mean (circular yaw); covariance includes each particle's pending C_i."""
        mean = weighted_pose_mean(self._means, self._weights)
        cov = weighted_pose_covariance(self._means, self._weights, mean, spread=self._covs)
        return PoseEstimate(self.last_stamp, mean, cov)

    def particles(self) -> tuple[np.ndarray, np.ndarray]:
        return self._means.copy(), self._weights.copy()

    def landmarks(self) -> LandmarkMap:
        """Per landmark the particle mixture collapsed to its mean and covariance."""
        w = self._weights
        positions = np.einsum("n,nkd->kd", w, self._mu)
        d = self._mu - positions[None]
        cov = np.einsum("n,nkij->kij", w, self._sigma + d[..., :, None] * d[..., None, :])
        return LandmarkMap(ids=self._book.ids.copy(), positions=positions, covariances=cov,
                           n_obs=self._book.n_obs.copy(),
                           confirmed=self._book.n_obs >= self.config.association.confirm_observations)
