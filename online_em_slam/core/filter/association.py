"""Likelihood-based data association for observations of unknown identity.

Shared by the online EM core and the baselines so that every method sees the
same gates.  The cost of pairing observation o with landmark k is its negative
log-likelihood: d2 + log det S for Gaussian noise (d2 the squared Mahalanobis
distance of the innovation, S its covariance), (dof + 2) log(1 + d2/dof) +
log det S for Student-t noise, whose gates are quantiles of d2's own law
(2 F(2, dof) instead of chi-square(2)).  At most one observation per landmark
per scan: the pairing is a linear assignment (scipy's Hungarian solver).
The particle filter's candidates, their moment-matched gates, the merging of
new landmarks one scan creates twice and the bound on how many one scan creates
are at the end.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from ..config import AssociationConfig, ObservationNoiseConfig
from ..models.angles import wrap_angle
from ..models.observation import (chi_square_2_quantile, innovation, inverse_observation, landmark_jacobian,
                                  mahalanobis_2d, predict_observation)
from ..weighted import weighted_outer, weighted_pose_mean, weighted_sum

NEW_LANDMARK = -1
AMBIGUOUS = -2
_FORBIDDEN = 1e12


@dataclass(frozen=True)
class Gates:
    """Squared-Mahalanobis thresholds at the gate probabilities of d2's law under the noise
    model (chi-square(2); 2 F(2, dof) for Student-t noise, ``dof`` None otherwise)."""

    associate: float
    create: float
    dof: float | None = None

    @classmethod
    def from_config(cls, config: AssociationConfig, noise: ObservationNoiseConfig | None = None) -> "Gates":
        dof = float(noise.dof) if noise is not None and noise.model == "student_t" else None
        return _gates(config.gate_probability, config.new_landmark_probability, dof)

    def cost(self, d2: np.ndarray, logdet: np.ndarray) -> np.ndarray:
        """Twice the negative log-likelihood of an innovation, up to a constant."""
        if self.dof is None:
            return d2 + logdet
        return (self.dof + 2.0) * np.log1p(d2 / self.dof) + logdet


@lru_cache(maxsize=8)
def _chi2_gates(associate: float, create: float) -> Gates:
    return Gates(chi_square_2_quantile(associate), chi_square_2_quantile(create))


def _gates(associate: float, create: float, dof: float | None) -> Gates:
    """Quantiles of d2: chi-square(2), or of 2 F(2, dof) (nu^T R^-1 nu / 2 of a 2-D t is F(2, dof)),
    whose CDF 1 - (1 + d2/dof)^(-dof/2) inverts in closed form (a learned dof moves every scan)."""
    if dof is None:
        return _chi2_gates(associate, create)
    return Gates(student_t_quantile(associate, dof), student_t_quantile(create, dof), dof)


def student_t_quantile(probability: float, dof: float) -> float:
    """The d2 below which a 2-D t_dof innovation falls with ``probability``: dof ((1-p)^(-2/dof) - 1)."""
    return float(dof * math.expm1(-2.0 / dof * math.log1p(-probability)))


def associate(observations: np.ndarray, predicted: np.ndarray, innovation_cov: np.ndarray,
              gates: Gates) -> tuple[np.ndarray, np.ndarray]:
    """Assign each observation to a landmark, to a new landmark, or drop it.

    observations   (O, 2) range, bearing
    predicted      (O, K, 2) or (K, 2): predicted (range, bearing) of each candidate landmark
    innovation_cov (O, K, 2, 2) or (K, 2, 2): covariance S of each innovation
    Returns (assignment (O,), d2 (O, K)) with assignment[o] = column index k,
    NEW_LANDMARK when o lies outside the creation gate of every landmark, or
    AMBIGUOUS when it is inside some gate but lost the assignment or sits
    between the two gates (dropping it avoids duplicate landmarks).
    """
    n_obs = observations.shape[0]
    k = predicted.shape[-2] if predicted.ndim >= 2 else 0
    if n_obs == 0:
        return np.zeros(0, dtype=int), np.zeros((0, k))
    if k == 0:
        return np.full(n_obs, NEW_LANDMARK, dtype=int), np.zeros((n_obs, 0))
    predicted = np.broadcast_to(predicted, (n_obs, k, 2))
    innovation_cov = np.broadcast_to(innovation_cov, (n_obs, k, 2, 2))
    nu = innovation(np.broadcast_to(observations[:, None, :], predicted.shape).copy(), predicted)
    d2, logdet = mahalanobis_2d(nu, innovation_cov)
    d2 = np.where(np.isfinite(d2), d2, np.inf)
    cost = np.where(d2 < gates.associate, gates.cost(d2, logdet), _FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    assignment = np.full(n_obs, AMBIGUOUS, dtype=int)
    ok = cost[rows, cols] < _FORBIDDEN
    assignment[rows[ok]] = cols[ok]
    unassigned = assignment == AMBIGUOUS
    far = d2.min(axis=1) > gates.create
    assignment[unassigned & far] = NEW_LANDMARK
    return assignment, d2


@dataclass
class AssociationPlan:
    """One scan's decisions: observations that update a landmark row, observations that create one.

    create_ids holds the observation's id, or None where the estimator assigns a fresh id.
    """

    update_obs: np.ndarray
    update_rows: np.ndarray
    create_obs: np.ndarray
    create_ids: list


def plan_associations(ids: np.ndarray, y: np.ndarray, rows_of_ids, candidates, gates: Gates,
                      drop) -> AssociationPlan:
    """Known ids (>= 0) to their row or a new landmark; unknown ids (-1) by likelihood.

    ids (O,), y (O, 2) the scan's ids and (range, bearing); ``rows_of_ids(ids)``
    gives each id's row (-1 if not in the map); ``candidates(unknown)`` gives
    (rows (K,), predicted (K, 2), S (U, K, 2, 2)) for the unknown-id
    observations, S including the observation noise; ``drop(reason, n)``
    counts.  A repeated id keeps its first observation (``duplicate_id``).
    Shared by online EM and the baselines, so every method sees the same gates.
    """
    known = np.flatnonzero(ids >= 0)
    if len(set(ids[known].tolist())) < known.size:           # a repeated id: its first observation
        first = np.sort(np.unique(ids[known], return_index=True)[1])
        drop("duplicate_id", known.size - first.size)
        known = known[first]
    rows = rows_of_ids(ids[known])
    update_obs, update_rows = [known[rows >= 0]], [rows[rows >= 0]]
    create_obs, create_ids = list(known[rows < 0]), [int(i) for i in ids[known[rows < 0]]]
    unknown = np.flatnonzero(ids < 0)
    if unknown.size:
        rows, predicted, S = candidates(unknown)
        if rows.size:
            assignment, _ = associate(y[unknown], predicted, S, gates)
        else:
            assignment = np.full(unknown.size, NEW_LANDMARK, dtype=int)
        hit = assignment >= 0
        update_obs.append(unknown[hit])
        update_rows.append(rows[assignment[hit]])
        drop("ambiguous_association", int((assignment == AMBIGUOUS).sum()))
        new = unknown[assignment == NEW_LANDMARK]
        create_obs.extend(new)
        create_ids.extend([None] * new.size)
    return AssociationPlan(np.concatenate(update_obs).astype(int), np.concatenate(update_rows).astype(int),
                           np.asarray(create_obs, dtype=int), create_ids)


# ----------------------------------------------------------------- the particle filter's gates
def candidate_rows(theta: np.ndarray, mean_sensor: np.ndarray, reach: float) -> np.ndarray:
    """Rows of the landmarks ``theta`` (M, 2) closer than ``reach`` to the mean sensor position."""
    if not theta.shape[0]:
        return np.zeros(0, dtype=int)
    dist = np.hypot(theta[:, 0] - mean_sensor[0], theta[:, 1] - mean_sensor[1])
    return np.flatnonzero(dist < reach)


def predicted_measurements(theta: np.ndarray, sensor: np.ndarray, w: np.ndarray, landmark_cov: np.ndarray,
                           config: AssociationConfig, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moment-matched predicted measurement (K, 2) and innovation covariance (U, K, 2, 2) per
    (observation, landmark), over particles ``sensor`` (N, 3) with weights ``w`` (N,).

    S = spread of h over particles + H (Sigma_theta + gate margin) H^T + R:
    pose and map uncertainty both widen the gate (dh/dp = -dh/dtheta, so a
    position margin enters like map uncertainty).  ``theta`` (K, 2) and
    ``landmark_cov`` (K, 2, 2) are the candidates', ``R`` (U, 2, 2) the observations' noise.
    """
    h = predict_observation(sensor[:, None, :], theta[None])                         # (N, K, 2)
    mean = weighted_sum(w, h)
    mean[:, 1] = np.arctan2(w @ np.sin(h[..., 1]), w @ np.cos(h[..., 1]))
    dev = h - mean[None]
    dev[..., 1] = wrap_angle(dev[..., 1])
    spread = weighted_outer(w, dev)
    H = landmark_jacobian(weighted_pose_mean(sensor, w)[None], theta)                # (K, 2, 2)
    map_cov = landmark_cov + config.gate_position_std ** 2 * np.eye(2)
    spread = spread + H @ map_cov @ np.swapaxes(H, -1, -2)
    spread[:, 1, 1] += config.gate_heading_std ** 2
    return mean, spread[None] + R[:, None]


def merge_close(positions: np.ndarray, obs_idx: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Of new landmark ``positions`` (k, 2) closer than ``radius`` to each other, the earlier is
    kept: (kept positions, their observation indices).  A k-d tree keeps this O(n log n) in
    memory and time for a hostile cloud, where an n x n distance matrix would not: the loop
    runs over the kept landmarks (one neighbour query each), never over the pairs, which a
    cloud of coincident points makes n^2 / 2."""
    if positions.shape[0] < 2:
        return positions, obs_idx
    tree = cKDTree(positions)
    keep = np.ones(positions.shape[0], dtype=bool)
    for i in range(positions.shape[0]):
        if keep[i]:
            near = np.asarray(tree.query_ball_point(positions[i], radius), dtype=int)
            keep[near[near > i]] = False
    return positions[keep], obs_idx[keep]


def nearest_first(ranges: np.ndarray, limit: int) -> np.ndarray:
    """Mask of the ``limit`` smallest ``ranges`` (ties: the earlier observation), in scan order.

    The per-scan bound on new landmarks (``association.max_new_landmarks_per_scan``):
    a near observation's inverse is the most precise start for a landmark, and the
    dropped far ones are created on a later scan if they are real."""
    ranges = np.asarray(ranges, dtype=float).reshape(-1)
    keep = np.ones(ranges.size, dtype=bool)
    if ranges.size > limit:
        keep[:] = False
        keep[np.argsort(ranges, kind="stable")[:max(int(limit), 0)]] = True
    return keep


def creations(plan, y: np.ndarray, mean_sensor: np.ndarray, table, assoc: AssociationConfig, merge_radius: float,
              drop, drops) -> tuple[np.ndarray, list[int], np.ndarray]:
    """(positions (K, 2), ids, prunable (K,)) of the landmarks a scan's plan creates, by
    inverting h at the mean sensor pose; prunable: created without an id from the sensor.

    Unknown-id creations closer than ``merge_radius`` are merged first (counted in
    ``drops`` as ``merged_new_landmark``); of the rest the ``max_new_landmarks_per_scan``
    nearest are kept (``new_landmark_limit``), and creations beyond ``max_landmarks`` are
    dropped (``map_full``).  The kept creations, in the plan's order, are the first entries
    of ``plan.create_obs`` afterwards.
    """
    given = np.array([i is not None for i in plan.create_ids], dtype=bool)
    positions = inverse_observation(mean_sensor[None], y[plan.create_obs]).reshape(-1, 2)
    fresh_pos, fresh_obs = merge_close(positions[~given], plan.create_obs[~given], merge_radius)
    if fresh_obs.size < int((~given).sum()):
        drops["merged_new_landmark"] += int((~given).sum() - fresh_obs.size)
    known_ids = np.array([i for i in plan.create_ids if i is not None], dtype=np.int64)
    obs_idx = np.concatenate([plan.create_obs[given], fresh_obs]).astype(int)
    positions = np.vstack([positions[given], fresh_pos]).reshape(-1, 2)
    keep = nearest_first(y[obs_idx, 0], assoc.max_new_landmarks_per_scan)
    drop("new_landmark_limit", int(keep.size - keep.sum()))
    n_given = int(given.sum())
    ids = [int(i) for i in known_ids[keep[:n_given]]]
    ids += table.next_ids(int(keep[n_given:].sum()), ids)
    plan.create_obs, positions = obs_idx[keep], positions[keep]
    prunable = np.arange(len(ids)) >= len(ids) - int(keep[n_given:].sum())        # the fresh ids come last
    room = max(assoc.max_landmarks - len(table), 0)
    drop("map_full", len(ids) - room)
    return positions[:room], ids[:room], prunable[:room]
