"""Particle online EM SLAM: the public estimator (ALGORITHM.md sections 2-4).

The pose is the hidden state of an HMM and is tracked by a particle filter;
the landmark map theta is a parameter, updated by the M-step from smoothed
sufficient statistics.  One *filter step* happens per observation scan (and,
without observations, every ``motion.max_prediction_interval`` seconds); the
controls or odometry increments in between are compounded into the Gaussian
transition (T) of ``motion.py``, so the O(N^2) smoother runs once per scan,
not once per 40 Hz control message.
"""
from __future__ import annotations

import os
import tempfile
import time
from collections import Counter

import numpy as np

from . import motion as motion_models
from .angles import wrap_angle
from .association import AMBIGUOUS, NEW_LANDMARK, Gates, associate
from .config import SlamConfig
from .observation import (innovation, inv_det_2x2, inverse_observation, landmark_jacobian,
                          noise_covariance, noise_loglik, component_precision_weight,
                          predict_observation, sensor_poses)
from .particles import (effective_sample_size, normalize_log_weights, sample_gaussians,
                        systematic_resample, weighted_outer, weighted_pose_covariance,
                        weighted_pose_mean, weighted_sum)
from .statistics import (STAT_DIM, backward_kernel, differing_landmarks, forward_smooth, information_covariance,
                         m_step, observation_statistics, paris_indices, paris_smooth)
from .types import LandmarkMap, Observations, PoseEstimate, StepReport

MAP_FORMAT_VERSION = 1


class OnlineEMSlam:
    """Particle online EM / Block Online EM landmark SLAM.

    Feed motion with :meth:`add_control` (bicycle, acfr, unicycle models) or
    :meth:`add_odometry` (odometry model), observation scans with
    :meth:`add_observations`; read :meth:`pose`, :meth:`particles` and
    :meth:`landmarks`.  Inputs that cannot be used are dropped and counted in
    :attr:`drops` by reason; no input raises or produces NaN.
    """

    def __init__(self, config: SlamConfig | None = None, initial_pose=(0.0, 0.0, 0.0),
                 stamp: float | None = None) -> None:
        self.config = (config or SlamConfig()).validate()
        self._gates = Gates.from_config(self.config.association)
        self.drops: Counter[str] = Counter()
        self.reset(initial_pose, stamp)

    # ------------------------------------------------------------------ state
    def reset(self, initial_pose=None, stamp: float | None = None) -> None:
        """Forget map, statistics and trajectory; restart at ``initial_pose``."""
        cfg = self.config
        self._rng = np.random.default_rng(cfg.filter.seed)
        n = cfg.filter.num_particles
        pose = np.asarray(initial_pose if initial_pose is not None else self._initial_pose, dtype=float)
        self._initial_pose = pose.copy()
        self._particles = np.tile(pose, (n, 1))
        std = np.asarray(cfg.filter.initial_pose_std, dtype=float)
        if np.any(std > 0):
            self._particles += self._rng.standard_normal((n, 3)) * std
            self._particles[:, 2] = wrap_angle(self._particles[:, 2])
        self._log_w = np.full(n, -np.log(n))
        self._pred_mean = self._particles.copy()
        self._pred_cov = np.zeros((n, 3, 3))
        self._pending_controls: list[np.ndarray] = []
        self._pending_dts: list[float] = []
        self._resample_pending = False
        self._time: float | None = stamp
        self._anchor_time: float | None = stamp
        self._held_control: np.ndarray | None = None
        self._last_odom: np.ndarray | None = None
        self._step = 0
        self._ess = float(n)
        # Landmark parameter theta and its bookkeeping, one row per landmark.
        self._theta = np.zeros((0, 2))
        self._ids = np.zeros(0, dtype=np.int64)
        self._count = np.zeros(0, dtype=np.int64)      # EM updates n_k (step sizes)
        self._inv_n = np.zeros(0)                      # sum of squared SA weights (covariance)
        self._n_obs = np.zeros(0, dtype=np.int64)
        self._created = np.zeros(0, dtype=np.int64)
        self._confirmed = np.zeros(0, dtype=bool)
        self._stats = np.zeros((0, STAT_DIM))          # smoothed statistic S_k of the last M-step
        self._spread = np.zeros((0, 2, 2))             # pose-induced landmark covariance (SA average)
        self._tau = np.zeros((n, 0, STAT_DIM))         # per-particle auxiliary statistics
        self._differing = np.zeros(0, dtype=bool)      # tau may still differ across particles
        # Block Online EM state.
        self._block_index = 1
        self._block_end = cfg.em.block_initial_length
        self._block_count = np.zeros(0, dtype=np.int64)
        self._avg_stats = np.zeros((0, STAT_DIM))
        self._avg_count = np.zeros(0, dtype=np.int64)

    def start_new_pass(self, initial_pose=None, stamp: float | None = None) -> None:
        """Prepare another pass over the same data: batch EM by repeated passes.

        The map estimate theta (and the landmark ids and observation counts)
        is kept as the starting point; the statistics, step-size counts and the
        filter restart, so the next pass computes an E-step under the current
        map and its M-steps replace the previous pass's statistics.  This is
        for offline diagnostics (how far EM is from its fixed point); the
        online use is a single pass.
        """
        # The last statistics and spreads stay until each landmark's first update of the
        # new pass replaces them (step size 1): they give the map uncertainty meanwhile.
        kept = {name: getattr(self, name).copy()
                for name in ("_theta", "_ids", "_n_obs", "_confirmed", "_stats", "_spread", "_inv_n")}
        self.reset(initial_pose, stamp)
        self._add_landmarks(kept.pop("_theta"), kept.pop("_ids"))
        for name, value in kept.items():
            setattr(self, name, value)

    @property
    def last_stamp(self) -> float | None:
        return self._time

    @property
    def step_count(self) -> int:
        return self._step

    @property
    def effective_sample_size(self) -> float:
        return self._ess

    # ------------------------------------------------------------------ inputs
    def _accept_stamp(self, stamp: float) -> bool:
        if not np.isfinite(stamp):
            self.drops["non_finite_stamp"] += 1
            return False
        if self._time is not None and stamp < self._time:
            self.drops["out_of_order"] += 1
            return False
        return True

    def _predict(self, control: np.ndarray, dt: float) -> None:
        """Queue one motion segment; :meth:`_flush_motion` compounds the queue into (T)."""
        if dt > self.config.motion.max_step:
            self.drops["large_time_step_clipped"] += 1
            dt = self.config.motion.max_step
        self._pending_controls.append(control)
        self._pending_dts.append(dt)

    def _flush_motion(self) -> None:
        """Compound the queued control segments into the transition (T) in one pass.

        Control messages (40 Hz on the KTH ute) outnumber scans; integrating
        them together when a scan or a pose query needs them costs one
        vectorised call instead of one per message (motion.integrate_segments).
        """
        if not self._pending_dts:
            return
        self._pred_mean, self._pred_cov = motion_models.integrate_segments(
            self.config.motion, self._pred_mean, self._pred_cov,
            np.array(self._pending_controls), np.array(self._pending_dts))
        self._pred_mean[:, 2] = wrap_angle(self._pred_mean[:, 2])
        self._pending_controls.clear()
        self._pending_dts.clear()

    def _advance_to(self, stamp: float) -> None:
        """Integrate the held control up to ``stamp`` (zero-order hold)."""
        if self._time is None:
            self._time = self._anchor_time = stamp
            return
        dt = stamp - self._time
        if dt > 0 and self._held_control is not None and self.config.motion.model != "odometry":
            self._predict(self._held_control, dt)
        self._time = stamp
        if stamp - self._anchor_time > self.config.motion.max_prediction_interval:
            # Keep the Gaussian transition local: a filter step without observations.
            self._filter_step(None)

    def add_control(self, stamp: float, control) -> bool:
        """Control u = (speed, steering angle or yaw rate) valid from ``stamp`` on."""
        if self.config.motion.model == "odometry":
            self.drops["control_ignored_by_odometry_model"] += 1
            return False
        control = np.asarray(control, dtype=float).reshape(-1)
        if control.shape[0] < 2 or not np.all(np.isfinite(control[:2])):
            self.drops["non_finite_control"] += 1
            return False
        if not self._accept_stamp(stamp):
            return False
        self._advance_to(float(stamp))
        self._held_control = control[:2].copy()
        return True

    def add_odometry(self, stamp: float, odom_pose) -> bool:
        """Odometry-frame pose (x, y, yaw); the increment since the previous one drives motion."""
        odom_pose = np.asarray(odom_pose, dtype=float).reshape(-1)
        if odom_pose.shape[0] < 3 or not np.all(np.isfinite(odom_pose[:3])):
            self.drops["non_finite_odometry"] += 1
            return False
        if not self._accept_stamp(stamp):
            return False
        stamp = float(stamp)
        if self.config.motion.model == "odometry" and self._last_odom is not None and self._time is not None:
            increment = motion_models.odometry_increment(self._last_odom, odom_pose)
            self._predict(increment, max(stamp - self._time, 0.0))
        self._last_odom = odom_pose[:3].copy()
        self._advance_to(stamp)
        return True

    def add_observations(self, stamp: float, observations: Observations) -> StepReport:
        """Run one filter step and EM update with a scan of range-bearing observations."""
        started = time.perf_counter()
        report = StepReport(n_observations=len(observations))
        if not self._accept_stamp(stamp):
            report.dropped["out_of_order"] = len(observations) or 1
            return report
        self._advance_to(float(stamp))
        observations = self._valid_observations(observations, report)
        self._filter_step(observations, report)
        report.ess = self._ess
        report.duration = time.perf_counter() - started
        return report

    def _valid_observations(self, obs: Observations, report: StepReport) -> Observations:
        sensor = self.config.sensor
        finite = np.isfinite(obs.ranges) & np.isfinite(obs.bearings)
        in_range = finite & (obs.ranges >= max(sensor.min_range, 0.0)) & (obs.ranges <= sensor.max_range)
        for reason, mask in (("invalid_observation", ~finite | (finite & (obs.ranges < 0))),
                             ("observation_out_of_range", finite & (obs.ranges >= 0) & ~in_range)):
            if mask.any():
                report.dropped[reason] = report.dropped.get(reason, 0) + int(mask.sum())
                self.drops[reason] += int(mask.sum())
        return obs.subset(in_range) if not in_range.all() else obs

    # ------------------------------------------------------------------ map rows
    def _add_landmarks(self, positions: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Append landmarks; returns their row indices."""
        k = positions.shape[0]
        n = self._tau.shape[0]
        start = self._theta.shape[0]
        self._theta = np.vstack([self._theta, positions])
        self._ids = np.concatenate([self._ids, ids.astype(np.int64)])
        self._count = np.concatenate([self._count, np.zeros(k, dtype=np.int64)])
        self._inv_n = np.concatenate([self._inv_n, np.ones(k)])
        self._n_obs = np.concatenate([self._n_obs, np.zeros(k, dtype=np.int64)])
        self._created = np.concatenate([self._created, np.full(k, self._step, dtype=np.int64)])
        self._confirmed = np.concatenate([self._confirmed, np.zeros(k, dtype=bool)])
        self._stats = np.vstack([self._stats, np.zeros((k, STAT_DIM))])
        self._spread = np.concatenate([self._spread, np.zeros((k, 2, 2))])
        self._tau = np.concatenate([self._tau, np.zeros((n, k, STAT_DIM))], axis=1)
        self._differing = np.concatenate([self._differing, np.zeros(k, dtype=bool)])
        self._block_count = np.concatenate([self._block_count, np.zeros(k, dtype=np.int64)])
        self._avg_stats = np.vstack([self._avg_stats, np.zeros((k, STAT_DIM))])
        self._avg_count = np.concatenate([self._avg_count, np.zeros(k, dtype=np.int64)])
        return np.arange(start, start + k)

    def _keep_landmarks(self, keep: np.ndarray) -> None:
        for name in ("_theta", "_ids", "_count", "_inv_n", "_n_obs", "_created", "_confirmed",
                     "_stats", "_spread", "_block_count", "_avg_stats", "_avg_count"):
            setattr(self, name, getattr(self, name)[keep])
        self._tau = self._tau[:, keep]
        self._differing = self._differing[keep]

    def _next_ids(self, k: int, pending: list[int]) -> list[int]:
        """Ids for landmarks created from unknown-id observations: above every id in use."""
        start = max([int(self._ids.max()) if self._ids.size else -1] + pending) + 1
        return list(range(start, start + k))

    def _landmark_covariances(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Map uncertainty: measurement part q A^-1 plus the spread of the
        per-particle solutions A_i^-1 b_i, which carries the pose uncertainty
        under which the landmark was observed, blended with the same step sizes."""
        return information_covariance(self._stats[rows], self._inv_n[rows]) + self._spread[rows]

    # ------------------------------------------------------------------ filter step
    def _filter_step(self, obs: Observations | None, report: StepReport | None = None) -> None:
        cfg = self.config
        report = report if report is not None else StepReport()
        self._flush_motion()
        n = self._particles.shape[0]
        # 1. Ancestors (resampling decided on the last ESS) and proposal draws from (T).
        log_w_prev = self._log_w
        if self._resample_pending:
            ancestors = systematic_resample(np.exp(log_w_prev), self._rng)
            log_prior = np.full(n, -np.log(n))
        else:
            ancestors = np.arange(n)
            log_prior = log_w_prev
        trans_cov = self._pred_cov + motion_models.step_jitter(cfg.motion)
        particles = sample_gaussians(self._pred_mean[ancestors], trans_cov[ancestors], self._rng)
        log_w = log_prior.copy()

        # 2. Association and observation likelihood under theta_{t-1}.
        pairs_obs, pairs_lm = np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        sensor = sensor_poses(particles, cfg.sensor)
        if obs is not None and len(obs):
            pairs_obs, pairs_lm = self._associate(obs, sensor, np.exp(log_prior - log_prior.max()), report)
        stats_new = spread_new = None
        if pairs_obs.size:
            y = np.stack([obs.ranges[pairs_obs], obs.bearings[pairs_obs]], axis=-1)        # (P, 2)
            R = noise_covariance(cfg.noise, obs.ranges[pairs_obs],
                                 None if obs.range_std is None else obs.range_std[pairs_obs],
                                 None if obs.bearing_std is None else obs.bearing_std[pairs_obs])
            theta_bar = self._theta[pairs_lm]                                             # (P, 2)
            predicted = predict_observation(sensor[:, None, :], theta_bar[None, :, :])    # (N, P, 2)
            nu = innovation(np.broadcast_to(y, predicted.shape).copy(), predicted)
            H = landmark_jacobian(sensor[:, None, :], theta_bar[None, :, :])              # (N, P, 2, 2)
            weighting = self._n_obs[pairs_lm] >= cfg.association.min_observations_for_weighting
            if weighting.any():
                S = np.broadcast_to(R, H.shape).copy()
                if cfg.em.inflate_with_map_uncertainty:
                    cov = self._landmark_covariances(pairs_lm)
                    S += H @ cov[None] @ np.swapaxes(H, -1, -2)
                loglik, _ = noise_loglik(cfg.noise, nu, S)
                log_w = log_w + np.where(weighting[None, :], loglik, 0.0).sum(axis=1)
            _, resp = noise_loglik(cfg.noise, nu, np.broadcast_to(R, H.shape))
            R_inv, _ = inv_det_2x2(R)
            precision = R_inv[None] * component_precision_weight(cfg.noise, resp)[..., None, None]
            stats_new = observation_statistics(H, precision, nu, theta_bar[None])          # (N, P, 5)
            spread_new = self._inverse_observation_spread(sensor, y, weights_prior=np.exp(log_prior - log_prior.max()))
            self._n_obs[pairs_lm] += 1
            report.n_associated = int(pairs_obs.size)

        weights, _ = normalize_log_weights(log_w)
        if not np.all(np.isfinite(log_w)):
            self.drops["degenerate_weights"] += 1

        # 3. Smoothing of the auxiliary statistics (forward-only / PaRIS / ancestry).
        if self._tau.shape[1]:
            self._tau = self._smooth(self._tau, log_w_prev, trans_cov, particles, ancestors)

        # 4. EM: blend (online) or accumulate (block) the new statistics, then the M-step.
        if cfg.em.algorithm == "online":
            self._online_em_update(pairs_lm, stats_new, spread_new, weights)
        else:
            self._block_em_update(pairs_lm, stats_new, spread_new, weights)

        # 5. New anchors for the next transition.
        self._particles = particles
        self._log_w = np.log(np.maximum(weights, 1e-300))
        self._pred_mean = particles.copy()
        self._pred_cov = np.zeros_like(self._pred_cov)
        self._ess = effective_sample_size(weights)
        self._resample_pending = self._ess < cfg.filter.resample_threshold * n
        self._anchor_time = self._time
        self._step += 1
        report.n_pruned = self._prune_tentative()

    def _inverse_observation_spread(self, sensor: np.ndarray, y: np.ndarray, weights_prior: np.ndarray) -> np.ndarray:
        """Weighted covariance over particles of inverse_observation(sensor_i, y): (P, 2, 2).

        It is how far the landmark position implied by one observation moves
        with the pose uncertainty at that time; pose errors are correlated over
        a pass, so it is averaged, not divided by the number of observations.
        """
        w = weights_prior / weights_prior.sum()
        points = inverse_observation(sensor[:, None, :], y[None])                         # (N, P, 2)
        dev = points - weighted_sum(w, points)[None]
        return weighted_outer(w, dev)

    def _smooth(self, tau_prev, log_w_prev, trans_cov, particles, ancestors) -> np.ndarray:
        smoother = self.config.filter.smoother
        # Both kernels average the previous statistics (rows sum to one), so a
        # landmark whose statistic is already the same in every particle keeps
        # it: only the landmarks that still differ across particles are smoothed.
        # In a large map most landmarks are out of sight and collapsed; the flag
        # spares the O(N M) test on them, and is raised again by an observation.
        candidates = np.flatnonzero(self._differing)
        if candidates.size:
            self._differing[candidates] = differing_landmarks(tau_prev[:, candidates])
        if smoother == "ancestry":
            return tau_prev[ancestors]
        active = np.flatnonzero(self._differing)
        if not active.size:
            return tau_prev
        if smoother == "paris":
            idx = paris_indices(log_w_prev, self._pred_mean, trans_cov, particles,
                                self.config.filter.paris_draws, self._rng)
            tau_prev[:, active] = paris_smooth(tau_prev[:, active], idx)
        else:
            kernel = backward_kernel(log_w_prev, self._pred_mean, trans_cov, particles)
            tau_prev[:, active] = forward_smooth(tau_prev[:, active], kernel)
        return tau_prev

    def _online_em_update(self, rows: np.ndarray, stats_new, spread_new, weights: np.ndarray) -> None:
        """tau <- (1 - gamma_n) tau + gamma_n s for the observed landmarks, gamma_n = n^-alpha."""
        em = self.config.em
        if rows.size:
            self._count[rows] += 1
            gamma = self._count[rows].astype(float) ** (-em.step_size_exponent)
            self._tau[:, rows] = (1.0 - gamma)[None, :, None] * self._tau[:, rows] + gamma[None, :, None] * stats_new
            self._spread[rows] = (1.0 - gamma)[:, None, None] * self._spread[rows] + gamma[:, None, None] * spread_new
            self._inv_n[rows] = (1.0 - gamma) ** 2 * self._inv_n[rows] + gamma ** 2
            self._differing[rows] = True
        # A statistic equal in every particle has the same weighted mean whatever
        # the weights: its M-step would return the current theta.
        changed = np.flatnonzero(self._differing)
        if changed.size:
            stats = weighted_sum(weights, self._tau[:, changed])
            self._apply_m_step(stats, self._count[changed] >= em.min_updates_before_mstep, changed)

    def _block_em_update(self, rows: np.ndarray, stats_new, spread_new, weights: np.ndarray) -> None:
        """Block Online EM: theta fixed within a block, statistics summed, M-step at block end."""
        em = self.config.em
        if rows.size:
            # Running mean of the pose-induced spread over all observations.
            share = 1.0 / (self._count[rows] + self._block_count[rows] + 1.0)
            self._spread[rows] += share[:, None, None] * (spread_new - self._spread[rows])
            self._tau[:, rows] += stats_new
            self._block_count[rows] += 1
            self._differing[rows] = True
            fresh = rows[self._count[rows] == 0]
            if fresh.size:
                # A landmark first seen inside a block has no block estimate yet: until
                # its first block ends it is estimated from the running block mean, so
                # the filter does not localise against a single-observation guess.
                stats = weighted_sum(weights, self._tau[:, fresh]) / self._block_count[fresh, None]
                theta, ok = m_step(stats)
                self._theta[fresh[ok]] = theta[ok]
                self._stats[fresh] = stats
                self._inv_n[fresh] = 1.0 / self._block_count[fresh]
        if self._step + 1 < self._block_end:
            return
        seen = self._block_count > 0
        if seen.any():
            block_sum = weighted_sum(weights, self._tau[:, seen])
            counts = self._block_count[seen]
            if em.algorithm == "block_averaged":
                self._avg_stats[seen] += block_sum
                self._avg_count[seen] += counts
                total, total_count = self._avg_stats[seen], self._avg_count[seen]
            else:
                total, total_count = block_sum, counts
            stats = np.zeros_like(self._stats)
            stats[seen] = total / total_count[:, None]
            self._count[seen] += counts
            inv_n = self._inv_n.copy()
            inv_n[seen] = 1.0 / total_count
            self._inv_n = inv_n
            self._apply_m_step(stats, seen & (self._count >= em.min_updates_before_mstep))
        # Restart smoothing for the next block.
        self._tau[:] = 0.0
        self._differing[:] = False
        self._block_count[:] = 0
        self._block_index += 1
        length = int(np.ceil(em.block_initial_length * self._block_index ** em.block_growth))
        self._block_end = self._step + 1 + length

    def _apply_m_step(self, stats: np.ndarray, eligible: np.ndarray, rows: np.ndarray | slice = slice(None)) -> None:
        """theta = A^-1 b for the landmarks ``rows`` whose statistics are ``stats``."""
        theta, ok = m_step(stats)
        update = eligible & ok
        target = np.arange(self._theta.shape[0])[rows][update]
        self._theta[target] = theta[update]
        self._stats[target] = stats[update]

    # ------------------------------------------------------------------ association
    def _associate(self, obs: Observations, sensor: np.ndarray, prior_weights: np.ndarray,
                   report: StepReport) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (observation index, landmark row); creates landmarks as needed."""
        cfg = self.config
        w = prior_weights / prior_weights.sum()
        mean_sensor = weighted_pose_mean(sensor, w)
        known = obs.ids >= 0
        pair_o: list[np.ndarray] = []
        pair_l: list[np.ndarray] = []
        created_obs: list[int] = []
        created_pos: list[np.ndarray] = []
        created_ids: list[int] = []
        if known.any():
            idx = np.flatnonzero(known)
            ids = obs.ids[idx]
            _, first = np.unique(ids, return_index=True)
            if first.size < idx.size:
                dup = idx.size - first.size
                report.dropped["duplicate_id"] = report.dropped.get("duplicate_id", 0) + dup
                self.drops["duplicate_id"] += dup
            idx, ids = idx[np.sort(first)], ids[np.sort(first)]
            rows = self._rows_of_ids(ids)
            pair_o.append(idx[rows >= 0])
            pair_l.append(rows[rows >= 0])
            for o, i in zip(idx[rows < 0], ids[rows < 0]):
                created_obs.append(int(o))
                created_ids.append(int(i))
                created_pos.append(inverse_observation(mean_sensor, np.array([obs.ranges[o], obs.bearings[o]])))
        unknown = np.flatnonzero(~known)
        if unknown.size:
            y = np.stack([obs.ranges[unknown], obs.bearings[unknown]], axis=-1)
            rows = self._candidate_rows(mean_sensor)
            if rows.size:
                predicted, S = self._predicted_measurements(sensor, w, rows, obs, unknown)
                assignment, _ = associate(y, predicted, S, self._gates)
            else:
                assignment = np.full(unknown.size, NEW_LANDMARK, dtype=int)
            hit = assignment >= 0
            pair_o.append(unknown[hit])
            pair_l.append(rows[assignment[hit]] if rows.size else np.zeros(0, dtype=int))
            ambiguous = int((assignment == AMBIGUOUS).sum())
            if ambiguous:
                report.dropped["ambiguous_association"] = report.dropped.get("ambiguous_association", 0) + ambiguous
                self.drops["ambiguous_association"] += ambiguous
            new = unknown[assignment == NEW_LANDMARK]
            if new.size:
                positions = inverse_observation(mean_sensor[None], y[assignment == NEW_LANDMARK])
                positions, new = self._dedupe_new(positions, new)
                created_obs.extend(int(o) for o in new)
                created_pos.extend(positions)
                created_ids.extend(self._next_ids(len(new), created_ids))
        if created_obs:
            room = cfg.association.max_landmarks - self._theta.shape[0]
            if room < len(created_obs):
                lost = len(created_obs) - max(room, 0)
                self.drops["map_full"] += lost
                report.dropped["map_full"] = report.dropped.get("map_full", 0) + lost
                created_obs, created_pos, created_ids = (created_obs[:max(room, 0)], created_pos[:max(room, 0)],
                                                        created_ids[:max(room, 0)])
            if created_obs:
                new_rows = self._add_landmarks(np.array(created_pos).reshape(-1, 2), np.array(created_ids))
                pair_o.append(np.array(created_obs, dtype=int))
                pair_l.append(new_rows)
                report.n_created = len(created_obs)
        if not pair_o:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        return np.concatenate(pair_o).astype(int), np.concatenate(pair_l).astype(int)

    def _rows_of_ids(self, ids: np.ndarray) -> np.ndarray:
        """Map row of each landmark id, -1 where the id is not in the map."""
        if not self._ids.size:
            return np.full(ids.shape, -1, dtype=int)
        order = np.argsort(self._ids, kind="stable")
        sorted_ids = self._ids[order]
        pos = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.size - 1)
        return np.where(sorted_ids[pos] == ids, order[pos], -1).astype(int)

    def _dedupe_new(self, positions: np.ndarray, obs_idx: np.ndarray):
        """Two unexplained observations of one scan closer than the range noise make one landmark."""
        if positions.shape[0] < 2:
            return positions, obs_idx
        keep = np.ones(positions.shape[0], dtype=bool)
        radius = 2.0 * self.config.noise.sigma_range
        dist = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
        for i in range(positions.shape[0]):
            if keep[i]:
                keep[(dist[i] < radius) & (np.arange(len(keep)) > i)] = False
        dropped = int((~keep).sum())
        if dropped:
            self.drops["merged_new_landmark"] += dropped
        return positions[keep], obs_idx[keep]

    def _candidate_rows(self, mean_sensor: np.ndarray) -> np.ndarray:
        if not self._theta.shape[0]:
            return np.zeros(0, dtype=int)
        reach = self.config.sensor.max_range + 5.0 * self.config.noise.sigma_range + 5.0
        dist = np.hypot(self._theta[:, 0] - mean_sensor[0], self._theta[:, 1] - mean_sensor[1])
        return np.flatnonzero(dist < reach)

    def _predicted_measurements(self, sensor, w, rows, obs: Observations, unknown):
        """Moment-matched predicted measurement and innovation covariance per (obs, landmark).

        S = spread of h over particles + H (Sigma_theta + gate margin) H^T + R:
        pose and map uncertainty both widen the gate (dh/dp = -dh/dtheta, so a
        position margin enters like map uncertainty).
        """
        theta = self._theta[rows]
        h = predict_observation(sensor[:, None, :], theta[None])                         # (N, K, 2)
        mean = weighted_sum(w, h)
        mean[:, 1] = np.arctan2(w @ np.sin(h[..., 1]), w @ np.cos(h[..., 1]))
        dev = h - mean[None]
        dev[..., 1] = wrap_angle(dev[..., 1])
        spread = weighted_outer(w, dev)
        H = landmark_jacobian(weighted_pose_mean(sensor, w)[None], theta)                # (K, 2, 2)
        assoc = self.config.association
        map_cov = self._landmark_covariances(rows) + assoc.gate_position_std ** 2 * np.eye(2)
        spread = spread + H @ map_cov @ np.swapaxes(H, -1, -2)
        spread[:, 1, 1] += assoc.gate_heading_std ** 2
        R = noise_covariance(self.config.noise, obs.ranges[unknown],
                             None if obs.range_std is None else obs.range_std[unknown],
                             None if obs.bearing_std is None else obs.bearing_std[unknown])
        return mean, spread[None] + R[:, None]

    def _prune_tentative(self) -> int:
        assoc = self.config.association
        self._confirmed |= self._n_obs >= assoc.confirm_observations
        stale = ~self._confirmed & (self._step - self._created > assoc.tentative_timeout)
        if stale.any():
            self._keep_landmarks(~stale)
            return int(stale.sum())
        return 0

    # ------------------------------------------------------------------ outputs
    def pose(self) -> PoseEstimate:
        """Weighted mean pose at the last input stamp, with its covariance."""
        self._flush_motion()
        w = np.exp(self._log_w - self._log_w.max())
        w /= w.sum()
        mean = weighted_pose_mean(self._pred_mean, w)
        cov = weighted_pose_covariance(self._pred_mean, w, mean, self._pred_cov)
        return PoseEstimate(self._time, mean, cov)

    def particles(self) -> tuple[np.ndarray, np.ndarray]:
        """Particle poses (predicted to the last input stamp) and normalised weights."""
        self._flush_motion()
        w = np.exp(self._log_w - self._log_w.max())
        return self._pred_mean.copy(), w / w.sum()

    def landmarks(self, confirmed_only: bool = False) -> LandmarkMap:
        """Current map estimate theta with covariances q A^-1 and observation counts."""
        keep = self._confirmed if confirmed_only else np.ones(self._ids.shape[0], dtype=bool)
        cov = self._landmark_covariances()
        cov = np.where(np.isfinite(cov), cov, 0.0)
        return LandmarkMap(self._ids[keep].copy(), self._theta[keep].copy(), cov[keep],
                           self._n_obs[keep].copy(), self._confirmed[keep].copy())

    # ------------------------------------------------------------------ persistence
    _MAP_FIELDS = ("_theta", "_ids", "_count", "_inv_n", "_n_obs", "_confirmed", "_stats",
                   "_spread", "_avg_stats", "_avg_count")

    def save_map(self, path: str) -> None:
        """Write map, statistics, counts and pose atomically (core/mapfile.py).

        The values are validated first: a non-finite estimate never replaces a good
        file.  The directory must exist (callers decide where files may be created).
        """
        from . import mapfile  # noqa: PLC0415
        data = {name.lstrip("_"): getattr(self, name) for name in self._MAP_FIELDS}
        data["pose"] = self.pose().mean
        mapfile.write_map(path, data)

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        """Load a map written by :meth:`save_map`; EM continues from its statistics and counts.

        The file is validated completely before the state is touched; on any error
        (MapFileError, a ValueError naming the file) the estimate is left unchanged.
        """
        from . import mapfile  # noqa: PLC0415
        loaded = mapfile.read_map(path, max_landmarks=self.config.association.max_landmarks)
        m = loaded["theta"].shape[0]
        pose = loaded["pose"].copy()
        pose[2] = wrap_angle(pose[2])
        # reset() rebinds attributes rather than mutating arrays, so a shallow copy of
        # the instance dict is a complete snapshot to fall back to.
        snapshot = dict(self.__dict__)
        try:
            self.reset(pose if restore_pose else None, self._time)
            for name in self._MAP_FIELDS:
                setattr(self, name, loaded[name.lstrip("_")])
            n = self._particles.shape[0]
            self._created = np.zeros(m, dtype=np.int64)
            self._block_count = np.zeros(m, dtype=np.int64)
            # Particle-level statistics are not saved: every particle restarts from the
            # smoothed statistic, which is what the M-step used.
            if self.config.em.algorithm == "online":
                self._tau = np.broadcast_to(self._stats, (n, m, STAT_DIM)).copy()
            else:
                self._tau = np.zeros((n, m, STAT_DIM))
            self._differing = np.zeros(m, dtype=bool)
        except BaseException:
            self.__dict__.clear()
            self.__dict__.update(snapshot)
            raise
