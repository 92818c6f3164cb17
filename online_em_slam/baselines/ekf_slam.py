"""EKF-SLAM baseline: one Gaussian over the joint state (pose, landmarks).

State s = (x, y, phi, theta_1, ..., theta_K), covariance P.

Prediction (motion.propagate, N = 1):
    s_xx' = f(x, u),  P_xx' = F P_xx F^T + G Q G^T,  P_xl' = F P_xl             (E1)
Update with the stacked associated observations (H = [dh/dX, 0, dh/dtheta_k, 0]):
    S = H P H^T + R,  K = P H^T S^-1,  s' = s + K (y - h(s)),
    P' = (I - K H) P (I - K H)^T + K R K^T   (Joseph form, keeps P symmetric PSD) (E2)
New landmark from the inverse observation g(X, z) (covariance augmentation):
    theta = g(x, z),  P_ll = G_x P_xx G_x^T + G_z R G_z^T,  P_l* = G_x P_x*       (E3)
"""
from __future__ import annotations

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.filter.association import Gates
from ..core.models.motion import propagate, step_jitter
from ..core.models.observation import (innovation, landmark_jacobian, pose_jacobian, predict_observation,
                                sensor_poses, inverse_observation)
from ..core.types import LandmarkMap, Observations, PoseEstimate, StepReport
from ._common import BaselineFilter, LandmarkBook, inverse_observation_jacobians, plan_associations


def predict_joint(state: np.ndarray, P: np.ndarray, mean: np.ndarray, F: np.ndarray, Q: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(E1): only the pose block and the pose-landmark cross terms change."""
    state = state.copy()
    state[:3] = mean
    state[2] = wrap_angle(state[2])
    P = P.copy()
    P[:3, :] = F @ P[:3, :]
    P[:, :3] = P[:, :3] @ F.T
    P[:3, :3] += Q
    return state, P


def landmark_blocks(P: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Cross covariances P_xl (K, 3, 2) and marginal covariances P_ll (K, 2, 2) of every landmark."""
    Pxl = P[:3, 3:].reshape(3, K, 2).transpose(1, 0, 2)
    Pll = P[3:, 3:].reshape(K, 2, K, 2)[np.arange(K), :, np.arange(K), :]
    return Pxl, Pll


def predicted_measurements(state: np.ndarray, P: np.ndarray, sensor) -> tuple[np.ndarray, np.ndarray]:
    """h(s) for every landmark and S0 = H P H^T (without R): the association inputs.

    S0_k = Hx Pxx Hx^T + Hx Pxl_k Hl^T + Hl Plx_k Hx^T + Hl Pll_k Hl^T.
    """
    K = (state.shape[0] - 3) // 2
    pose, lms = state[:3], state[3:].reshape(K, 2)
    z_hat = predict_observation(sensor_poses(pose, sensor)[None, :], lms)
    Hx = pose_jacobian(pose[None, :], lms, sensor)
    Hl = landmark_jacobian(sensor_poses(pose, sensor)[None, :], lms)
    Pxl, Pll = landmark_blocks(P, K)
    cross = Hx @ Pxl @ Hl.transpose(0, 2, 1)
    S0 = Hx @ P[:3, :3] @ Hx.transpose(0, 2, 1) + cross + cross.transpose(0, 2, 1) \
        + Hl @ Pll @ Hl.transpose(0, 2, 1)
    return z_hat, S0


def joint_innovation(state: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, slots: np.ndarray,
                     sensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(E2)'s inputs for all m associated observations stacked: innovation nu (2m,),
    H (2m, n) and the block-diagonal R (2m, 2m)."""
    m, n = len(slots), state.shape[0]
    K = (n - 3) // 2
    pose, lms = state[:3], state[3:].reshape(K, 2)[slots]
    sp = sensor_poses(pose, sensor)[None, :]
    nu = innovation(z, predict_observation(sp, lms)).reshape(2 * m)
    H = np.zeros((2 * m, n))
    H[:, :3] = pose_jacobian(pose[None, :], lms, sensor).reshape(2 * m, 3)
    Hl = landmark_jacobian(sp, lms)
    for i, k in enumerate(slots):
        H[2 * i:2 * i + 2, 3 + 2 * k:5 + 2 * k] = Hl[i]
    Rb = np.zeros((2 * m, 2 * m))
    for i in range(m):
        Rb[2 * i:2 * i + 2, 2 * i:2 * i + 2] = R[i]
    return nu, H, Rb


def kalman_update(state: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray, Rb: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(E2) from :func:`joint_innovation`'s nu, H and R (Joseph form)."""
    PHt = P @ H.T
    S = H @ PHt + Rb
    gain = np.linalg.solve(S, PHt.T).T
    state = state + gain @ nu
    state[2] = wrap_angle(state[2])
    A = np.eye(state.shape[0]) - gain @ H
    P = A @ P @ A.T + gain @ Rb @ gain.T
    return state, 0.5 * (P + P.T)


def joint_update(state: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, slots: np.ndarray,
                 sensor) -> tuple[np.ndarray, np.ndarray]:
    """(E2) with all m associated observations stacked (2m rows)."""
    return kalman_update(state, P, *joint_innovation(state, P, z, R, slots, sensor))


def augment(state: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, sensor
            ) -> tuple[np.ndarray, np.ndarray]:
    """(E3): append one landmark initialised from observation z (range, bearing)."""
    pose = state[:3]
    theta = inverse_observation(sensor_poses(pose, sensor), z)
    Gx, Gz = inverse_observation_jacobians(pose, z, sensor)
    n = state.shape[0]
    cross = Gx @ P[:3, :]
    P_new = np.zeros((n + 2, n + 2))
    P_new[:n, :n] = P
    P_new[n:, :n] = cross
    P_new[:n, n:] = cross.T
    P_new[n:, n:] = Gx @ P[:3, :3] @ Gx.T + Gz @ R @ Gz.T
    return np.concatenate([state, theta]), P_new


def remove_landmarks(state: np.ndarray, P: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marginalise landmarks out of a Gaussian: drop their rows and columns."""
    index = np.concatenate([np.arange(3), 3 + np.stack([2 * np.flatnonzero(keep),
                                                         2 * np.flatnonzero(keep) + 1], 1).reshape(-1)])
    return state[index], P[np.ix_(index, index)]


class EkfSlam(BaselineFilter):
    """EKF-SLAM with the public API of :class:`OnlineEMSlam` (docs/API.md)."""

    def _reset_state(self, initial_pose: np.ndarray) -> None:
        self._state = initial_pose.astype(float).copy()
        self._P = np.diag(np.square(np.asarray(self.config.filter.initial_pose_std, dtype=float)))
        self._book = LandmarkBook()
        self._gates = Gates.from_config(self.config.association, self.config.noise)

    def _predict(self, control: np.ndarray, dt: float) -> None:
        mean, F, Q = propagate(self.config.motion, self._state[None, :3], control, dt)
        self._state, self._P = predict_joint(self._state, self._P, mean[0], F[0], Q[0])

    def _update(self, observations: Observations, R: np.ndarray, report: StepReport) -> None:
        sensor, assoc = self.config.sensor, self.config.association
        # Jitter once per scan keeps P_xx positive definite when the controls are exact.
        self._P[:3, :3] += step_jitter(self.config.motion)
        z = np.stack([observations.ranges, observations.bearings], axis=1)
        upd_obs, upd_slots, new_obs, new_ids = plan_associations(
            observations, self._book, lambda: predicted_measurements(self._state, self._P, sensor),
            R, self._gates, report, self._count)
        if upd_obs.size:
            self._state, self._P = joint_update(self._state, self._P, z[upd_obs], R[upd_obs],
                                                upd_slots, sensor)
            np.add.at(self._book.n_obs, upd_slots, 1)
        for o, landmark_id in zip(new_obs, new_ids):
            if len(self._book) >= assoc.max_landmarks:
                self._count(report, "map_full")
                continue
            self._state, self._P = augment(self._state, self._P, z[o], R[o], sensor)
            self._book.add(landmark_id, self._scan_count)
            report.n_created += 1
        report.n_associated = int(upd_obs.size)
        stale = self._book.stale(self._scan_count, assoc.confirm_observations, assoc.tentative_timeout)
        if stale.any():
            self._state, self._P = remove_landmarks(self._state, self._P, ~stale)
            self._book.keep(~stale)
            report.n_pruned = int(stale.sum())

    # -- outputs -------------------------------------------------------------------
    def pose(self) -> PoseEstimate:
        return PoseEstimate(self.last_stamp, self._state[:3].copy(), self._P[:3, :3].copy())

    def landmarks(self) -> LandmarkMap:
        K = len(self._book)
        _, Pll = landmark_blocks(self._P, K)
        return LandmarkMap(ids=self._book.ids.copy(), positions=self._state[3:].reshape(K, 2).copy(),
                           covariances=Pll.copy(), n_obs=self._book.n_obs.copy(),
                           confirmed=self._book.n_obs >= self.config.association.confirm_observations)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The joint mean and covariance (for consistency tests)."""
        return self._state.copy(), self._P.copy()
