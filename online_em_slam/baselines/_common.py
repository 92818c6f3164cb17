"""Input handling shared by the baseline estimators (EKF-SLAM, FastSLAM 2.0).

Mirrors the input contract of :class:`online_em_slam.core.filter.slam.OnlineEMSlam`
(docs/API.md): stamps in seconds, zero-order hold of controls, odometry poses
turned into body-frame increments, bad inputs dropped and counted in
``drops`` instead of raising.  Subclasses implement the estimator itself:
``_predict(control, dt)`` for one integration sub-step and
``_update(observations, R, report)`` for one scan.
"""
from __future__ import annotations

import math
import time
from collections import Counter

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.config import SlamConfig
from ..core.filter.association import plan_associations as core_plan
from ..core.filter.input_contract import MotionInput
from ..core.models.observation import noise_covariance
from ..core.types import Observations, StepReport


def prediction_substeps(dt: float, max_step: float) -> tuple[int, float]:
    """Split dt into n equal sub-steps no longer than ``max_step`` (Euler integration accuracy)."""
    n = max(1, int(math.ceil(dt / max_step - 1e-9)))
    return n, dt / n


class BaselineFilter:
    """Stamps, zero-order hold and input validation; see the module docstring."""

    def __init__(self, config: SlamConfig, initial_pose=(0.0, 0.0, 0.0), stamp: float | None = None):
        self.config = config.validate()
        self.drops: Counter = Counter()
        self._initial_stamp = None if stamp is None else float(stamp)
        self.reset(initial_pose)

    # -- to implement ------------------------------------------------------------
    def _reset_state(self, initial_pose: np.ndarray) -> None:
        raise NotImplementedError

    def _predict(self, control: np.ndarray, dt: float) -> None:
        raise NotImplementedError

    def _update(self, observations: Observations, R: np.ndarray, report: StepReport) -> None:
        raise NotImplementedError

    # -- public API ----------------------------------------------------------------
    def reset(self, initial_pose=None) -> None:
        """Forget the map and restart at ``initial_pose`` (default: the constructor's)."""
        if initial_pose is not None:
            self._initial_pose = np.asarray(initial_pose, dtype=float).reshape(3).copy()
        self._input = MotionInput(self.config.motion, self.drops, self._initial_stamp)
        self._scan_count = 0
        self._reset_state(self._initial_pose.copy())

    @property
    def last_stamp(self) -> float | None:
        return self._input.last_stamp

    def add_control(self, stamp: float, control) -> bool:
        """Propagate to ``stamp`` with the held control, then hold ``control`` (zero-order hold)."""
        u = self._input.control(stamp, control)
        if u is None or not self._advance(stamp):
            return False
        self._input.hold(float(stamp), u)
        return True

    def add_odometry(self, stamp: float, odom_pose) -> bool:
        """Apply the body-frame increment from the previous odometry pose (motion.uses_odometry)."""
        usable, increment, dt = self._input.odometry_motion(stamp, odom_pose)
        if not usable:
            return False
        if increment is not None:
            self._predict(increment, max(dt, 1e-6))
        return self._advance(stamp)

    def add_observations(self, stamp: float, observations: Observations) -> StepReport:
        """Propagate to ``stamp``, then update with the scan; returns what was done."""
        start = time.perf_counter()
        report = StepReport(n_observations=len(observations), dropped={})
        if not self._advance(stamp):
            report.dropped["out_of_order"] = len(observations) or 1
            report.duration = time.perf_counter() - start
            return report
        sensor = self.config.sensor
        good = np.isfinite(observations.ranges) & np.isfinite(observations.bearings)
        good &= observations.ranges >= 0
        self._count(report, "invalid_observation", int(np.sum(~good)))
        std_ok = observations.valid_std()
        self._count(report, "invalid_std", int(np.sum(good & ~std_ok)))
        good &= std_ok
        in_range = good & (observations.ranges >= sensor.min_range) & (observations.ranges <= sensor.max_range)
        self._count(report, "observation_out_of_range", int(np.sum(good & ~in_range)))
        kept = observations.subset(in_range)
        kept.bearings = wrap_angle(kept.bearings)
        R = noise_covariance(self.config.noise, kept.ranges, kept.range_std, kept.bearing_std)
        self._scan_count += 1
        self._update(kept, R, report)
        report.duration = time.perf_counter() - start
        return report

    # -- helpers ---------------------------------------------------------------------
    def _count(self, report: StepReport | None, reason: str, n: int = 1) -> None:
        if n <= 0:
            return
        self.drops[reason] += n
        if report is not None:
            report.dropped[reason] = report.dropped.get(reason, 0) + n

    def _advance(self, stamp: float) -> bool:
        """Propagate from ``last_stamp`` to ``stamp`` with the held control.

        False (and counted) for a bad stamp.  The gap is integrated in
        sub-steps of at most ``max_step``; gaps longer than
        ``max_prediction_interval`` are clipped to it (counted), because
        extrapolating a held control over a long gap is not credible.
        """
        held = self._input
        if not held.accept_stamp(stamp):
            return False
        stamp = float(stamp)
        if held.last_stamp is None:
            held.last_stamp = stamp
            return True
        motion = self.config.motion
        for control, dt in held.held_segments(stamp):       # none for the odometry model: nothing held
            if dt > motion.max_prediction_interval:
                self.drops["large_time_step_clipped"] += 1
                dt = motion.max_prediction_interval
            n, h = prediction_substeps(dt, motion.max_step)
            for _ in range(n):
                self._predict(control, h)
        return True


def inverse_observation_jacobians(poses: np.ndarray, observations: np.ndarray, sensor
                                  ) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the landmark initialisation g(X, z) = p_s + r (cos a, sin a), a = phi_s + b.

    G_x = dg/dX (..., 2, 3) includes the sensor lever arm; G_z = dg/dz (..., 2, 2).
    Used to augment covariances with a new landmark: Sigma_new = G_x P G_x^T + G_z R G_z^T.
    """
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    angle = poses[..., 2] + sensor.offset_yaw + observations[..., 1]
    ca, sa = np.cos(angle), np.sin(angle)
    r = observations[..., 0]
    shape = np.broadcast_shapes(c.shape, r.shape)
    Gx = np.zeros(shape + (2, 3))
    Gx[..., 0, 0] = 1.0
    Gx[..., 1, 1] = 1.0
    Gx[..., 0, 2] = -s * sensor.offset_x - c * sensor.offset_y - r * sa
    Gx[..., 1, 2] = c * sensor.offset_x - s * sensor.offset_y + r * ca
    Gz = np.empty(shape + (2, 2))
    Gz[..., 0, 0], Gz[..., 0, 1] = ca, -r * sa
    Gz[..., 1, 0], Gz[..., 1, 1] = sa, r * ca
    return Gx, Gz


class LandmarkBook:
    """Identity bookkeeping of the map slots shared by all particles / the EKF state.

    ``ids`` are the external ids (given ids, or fresh ones for landmarks created
    from unknown-id observations); ``tentative`` marks created-from-unknown
    landmarks that may be pruned if they are not re-observed.
    """

    def __init__(self) -> None:
        self.ids = np.zeros(0, dtype=np.int64)
        self.n_obs = np.zeros(0, dtype=np.int64)
        self.created = np.zeros(0, dtype=np.int64)
        self.prunable = np.zeros(0, dtype=bool)
        self.next_id = 0

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def slots(self, ids: np.ndarray) -> np.ndarray:
        """Slot of each id, -1 when unknown to the map."""
        lookup = {int(i): k for k, i in enumerate(self.ids)}
        return np.array([lookup.get(int(i), -1) for i in ids], dtype=np.int64)

    def add(self, landmark_id: int | None, scan: int) -> int:
        """Register a landmark (fresh id when None); returns its id."""
        prunable = landmark_id is None
        if landmark_id is None:
            landmark_id = self.next_id
        self.next_id = max(self.next_id, int(landmark_id) + 1)
        self.ids = np.append(self.ids, np.int64(landmark_id))
        self.n_obs = np.append(self.n_obs, 1)
        self.created = np.append(self.created, scan)
        self.prunable = np.append(self.prunable, prunable)
        return int(landmark_id)

    def stale(self, scan: int, confirm: int, timeout: int) -> np.ndarray:
        """Mask of tentative landmarks (fewer than ``confirm`` observations) older than ``timeout`` scans."""
        return self.prunable & (self.n_obs < confirm) & (scan - self.created > timeout)

    def keep(self, mask: np.ndarray) -> None:
        self.ids, self.n_obs = self.ids[mask], self.n_obs[mask]
        self.created, self.prunable = self.created[mask], self.prunable[mask]


def plan_associations(observations: Observations, book: LandmarkBook, predicted_fn, R: np.ndarray,
                      gates, report: StepReport, drop) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """The core's association plan (core/filter/association.py) over the baseline's slots.

    ``predicted_fn()`` returns (z_hat (K, 2), S0 (K, 2, 2)) for every slot; the
    innovation covariance of an unknown-id observation is S0 + R.  Returns
    (update_obs, update_slots, create_obs, create_ids), create_ids holding the
    given id or None for a fresh one.
    """
    y = np.stack([observations.ranges, observations.bearings], axis=1)

    def candidates(unknown):
        if not len(book):
            return np.zeros(0, dtype=int), np.zeros((0, 2)), np.zeros((unknown.size, 0, 2, 2))
        z_hat, S0 = predicted_fn()
        return np.arange(len(book)), z_hat, S0[None] + R[unknown][:, None]

    plan = core_plan(observations.ids, y, book.slots, candidates, gates, lambda reason, n: drop(report, reason, n))
    return plan.update_obs, plan.update_rows, plan.create_obs, plan.create_ids
