"""The seed's M-step: theta_k = A_k^-1 b_k on smoothed complete-data statistics.

docs/METHOD.md, "Complete-data M-step".  Each particle carries tau^i (N, M, 5), the
expectation of the accumulated statistics (S) given its pose; a smoother
(forward-only, PaRIS or ancestry: one piece of statistics.SMOOTHERS) carries tau
from the particles at t-1 to those at t, then the step's statistics are blended in with the step size
gamma_n (online EM) or summed over a block (Block Online EM), and the M-step
solves A_k theta_k = b_k on the weighted particle mean S = sum_i w^i tau^i.
"""
from __future__ import annotations

import numpy as np

from ..config import SlamConfig
from .step import FilterStepData
from ..mapping.landmarks import LandmarkTable
from ..models.observation import inverse_observation
from ..weighted import weighted_outer, weighted_sum
from .statistics import (STAT_DIM, differing_landmarks, information_covariance, m_step, make_smoother,
                         observation_statistics)


class CompleteDataEM:
    """Online EM or Block Online EM with the complete-data M-step, one landmark at a time."""

    def __init__(self, config: SlamConfig, n_particles: int, rng: np.random.Generator) -> None:
        self.config = config
        self.smoother = make_smoother(config.filter, rng)    # forward, paris or ancestry
        self.tau = np.zeros((n_particles, 0, STAT_DIM))   # per-particle auxiliary statistics
        self.stats = np.zeros((0, STAT_DIM))             # smoothed statistic S_k of the last M-step
        self.spread = np.zeros((0, 2, 2))                # pose-induced landmark covariance (SA average)
        self.count = np.zeros(0, dtype=np.int64)         # EM updates n_k (step sizes)
        self.inv_n = np.zeros(0)                         # sum of squared SA weights (covariance)
        self.differing = np.zeros(0, dtype=bool)         # tau may still differ across particles
        self.block_count = np.zeros(0, dtype=np.int64)
        self.avg_stats = np.zeros((0, STAT_DIM))
        self.avg_count = np.zeros(0, dtype=np.int64)
        self.block_index = 1
        self.block_end = config.em.block_initial_length

    _ROW_FIELDS = ("stats", "spread", "count", "inv_n", "differing", "block_count", "avg_stats", "avg_count")

    # ------------------------------------------------------------ rows
    def add_landmarks(self, count: int) -> None:
        n = self.tau.shape[0]
        self.tau = np.concatenate([self.tau, np.zeros((n, count, STAT_DIM))], axis=1)
        self.inv_n = np.concatenate([self.inv_n, np.ones(count)])
        for name in ("stats", "avg_stats"):
            setattr(self, name, np.vstack([getattr(self, name), np.zeros((count, STAT_DIM))]))
        self.spread = np.concatenate([self.spread, np.zeros((count, 2, 2))])
        for name in ("count", "block_count", "avg_count"):
            setattr(self, name, np.concatenate([getattr(self, name), np.zeros(count, dtype=np.int64)]))
        self.differing = np.concatenate([self.differing, np.zeros(count, dtype=bool)])

    def keep_landmarks(self, keep: np.ndarray) -> None:
        for name in self._ROW_FIELDS:
            setattr(self, name, getattr(self, name)[keep])
        self.tau = self.tau[:, keep]

    # ------------------------------------------------------------ EM update
    def update(self, data: FilterStepData, table: LandmarkTable) -> None:
        """Smooth tau to the new particles, blend in the step's statistics, M-step."""
        stats_new = spread_new = None
        if data.rows.size:
            theta_bar = table.theta[data.rows]
            stats_new = observation_statistics(data.H, data.precision, data.nu, theta_bar[None])   # (N, P, 5)
            spread_new = inverse_observation_spread(data.sensor, data.y, data.prior_weights)
        if self.tau.shape[1]:
            self.tau = self._smooth(data)
        if self.config.em.algorithm == "online":
            self._online_update(data.rows, stats_new, spread_new, data.weights, table)
        else:
            self._block_update(data, stats_new, spread_new, table)
        return None

    def _smooth(self, data: FilterStepData) -> np.ndarray:
        """tau from t-1 to t by the configured smoother (statistics.SMOOTHERS).

        The kernels average the previous statistics (rows sum to one), so a
        landmark whose statistic is already the same in every particle keeps it:
        only the landmarks that still differ are smoothed (unless the smoother
        takes the whole table).  In a large map most landmarks are out of sight
        and collapsed; an observation raises the flag again.
        """
        tau = self.tau
        candidates = np.flatnonzero(self.differing)
        if candidates.size:
            self.differing[candidates] = differing_landmarks(tau[:, candidates])
        if self.smoother.whole_table:
            return self.smoother.update(tau, data)
        active = np.flatnonzero(self.differing)
        if active.size:
            tau[:, active] = self.smoother.update(tau[:, active], data)
        return tau

    def _online_update(self, rows, stats_new, spread_new, weights, table: LandmarkTable) -> None:
        """tau <- (1 - gamma_n) tau + gamma_n s for the observed landmarks, gamma_n = n^-alpha."""
        em = self.config.em
        if rows.size:
            self.count[rows] += 1
            gamma = self.count[rows].astype(float) ** (-em.step_size_exponent)
            self.tau[:, rows] = (1.0 - gamma)[None, :, None] * self.tau[:, rows] + gamma[None, :, None] * stats_new
            self.spread[rows] = (1.0 - gamma)[:, None, None] * self.spread[rows] + gamma[:, None, None] * spread_new
            self.inv_n[rows] = (1.0 - gamma) ** 2 * self.inv_n[rows] + gamma ** 2
            self.differing[rows] = True
        # A statistic equal in every particle has the same weighted mean whatever
        # the weights: its M-step would return the current theta.
        changed = np.flatnonzero(self.differing)
        if changed.size:
            stats = weighted_sum(weights, self.tau[:, changed])
            self._apply_m_step(stats, self.count[changed] >= em.min_updates_before_mstep, changed, table)

    def _block_update(self, data: FilterStepData, stats_new, spread_new, table: LandmarkTable) -> None:
        """Block Online EM: theta fixed within a block, statistics summed, M-step at block end."""
        rows = data.rows
        if rows.size:
            self._accumulate_block(rows, stats_new, spread_new, data.weights, table)
        if data.step + 1 < self.block_end:
            return
        seen = self.block_count > 0
        if seen.any():
            self._end_block_m_step(seen, data.weights, table)
        # Restart smoothing for the next block.
        self.tau[:] = 0.0
        self.differing[:] = False
        self.block_count[:] = 0
        self.block_index += 1
        em = self.config.em
        self.block_end = data.step + 1 + int(np.ceil(em.block_initial_length * self.block_index ** em.block_growth))

    def _accumulate_block(self, rows, stats_new, spread_new, weights, table: LandmarkTable) -> None:
        # Running mean of the pose-induced spread over all observations.
        share = 1.0 / (self.count[rows] + self.block_count[rows] + 1.0)
        self.spread[rows] += share[:, None, None] * (spread_new - self.spread[rows])
        self.tau[:, rows] += stats_new
        self.block_count[rows] += 1
        self.differing[rows] = True
        fresh = rows[self.count[rows] == 0]
        if fresh.size:
            # A landmark first seen inside a block has no block estimate yet: until
            # its first block ends it is estimated from the running block mean, so
            # the filter does not localise against a single-observation guess.
            stats = weighted_sum(weights, self.tau[:, fresh]) / self.block_count[fresh, None]
            theta, ok = m_step(stats)
            table.theta[fresh[ok]] = theta[ok]
            self.stats[fresh] = stats
            self.inv_n[fresh] = 1.0 / self.block_count[fresh]

    def _end_block_m_step(self, seen: np.ndarray, weights: np.ndarray, table: LandmarkTable) -> None:
        block_sum = weighted_sum(weights, self.tau[:, seen])
        counts = self.block_count[seen]
        if self.config.em.algorithm == "block_averaged":
            self.avg_stats[seen] += block_sum
            self.avg_count[seen] += counts
            total, total_count = self.avg_stats[seen], self.avg_count[seen]
        else:
            total, total_count = block_sum, counts
        stats = np.zeros_like(self.stats)
        stats[seen] = total / total_count[:, None]
        self.count[seen] += counts
        self.inv_n = self.inv_n.copy()
        self.inv_n[seen] = 1.0 / total_count
        self._apply_m_step(stats, seen & (self.count >= self.config.em.min_updates_before_mstep),
                           slice(None), table)

    def _apply_m_step(self, stats, eligible, rows, table: LandmarkTable) -> None:
        """theta = A^-1 b for the landmarks ``rows`` whose statistics are ``stats``."""
        theta, ok = m_step(stats)
        update = eligible & ok
        target = np.arange(len(table))[rows][update]
        table.theta[target] = theta[update]
        self.stats[target] = stats[update]

    def restart_pose(self, pose: np.ndarray, pose_std, table: LandmarkTable,
                     weights: np.ndarray | None = None) -> None:
        """The filter was re-initialised: the new particles share no ancestry with the
        old ones, so each landmark's statistic restarts as the old weighted mean S."""
        if self.tau.shape[1]:
            w = np.full(self.tau.shape[0], 1.0 / self.tau.shape[0]) if weights is None else weights
            self.tau[:] = weighted_sum(w, self.tau)[None]
        self.differing[:] = False

    # ------------------------------------------------------------ uncertainty
    def covariances(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Measurement part q A^-1 plus the spread of the per-particle solutions, which
        carries the pose uncertainty under which the landmark was observed."""
        return information_covariance(self.stats[rows], self.inv_n[rows]) + self.spread[rows]

    def map_covariances(self) -> np.ndarray:
        return self.covariances()

    # ------------------------------------------------------------ persistence
    def saved_arrays(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        return {"count": self.count, "inv_n": self.inv_n, "stats": self.stats, "spread": self.spread,
                "avg_stats": self.avg_stats, "avg_count": self.avg_count}

    def restore(self, arrays: dict[str, np.ndarray], theta: np.ndarray) -> None:
        """Continue from saved statistics; every particle restarts from the smoothed
        statistic, which is what the M-step used."""
        m = arrays["stats"].shape[0]
        self.add_landmarks(m)
        for name in ("count", "inv_n", "stats", "spread", "avg_stats", "avg_count"):
            setattr(self, name, np.array(arrays[name]))
        if self.config.em.algorithm == "online":
            self.tau = np.broadcast_to(self.stats, self.tau.shape).copy()


def inverse_observation_spread(sensor: np.ndarray, y: np.ndarray, prior_weights: np.ndarray) -> np.ndarray:
    """Weighted covariance over particles of inverse_observation(sensor_i, y): (P, 2, 2).

    It is how far the landmark position implied by one observation moves with
    the pose uncertainty at that time; pose errors are correlated over a pass,
    so it is averaged, not divided by the number of observations.
    """
    points = inverse_observation(sensor[:, None, :], y[None])                         # (N, P, 2)
    dev = points - weighted_sum(prior_weights, points)[None]
    return weighted_outer(prior_weights, dev)
