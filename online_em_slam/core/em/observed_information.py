"""The map's Gaussian in information form: the joint Gauss-Newton system with the poses integrated out.

docs/METHOD.md, "Observed-information M-step"; the factors and variables are in
segment_factors.py.  The stored system is the information matrix and vector over
z = [dx_key_1 .. dx_key_R; theta].  Folding a segment in changes the stored map block by a
rank-3 term plus terms on x_K and theta_S (:func:`segment_schur`), O(M^2) with a small
constant; the map is the minimiser, one Cholesky factorisation, O(M^3), per solve.  With one
segment and no map update in between, the solve is exactly one Gauss-Newton step of batch
least squares over every pose and landmark (test_observed_information.py checks this against
scipy).  observed_covariance.py holds the same Gaussian by its mean and covariance.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ..config import SensorConfig
from .segment_factors import MIN_PRIOR_STD, POSE_DIM, SegmentFactors, SegmentSystem, given_key, marginalize


class ObservedInformation(SegmentFactors):
    """Information form over [dx_key_1 .. dx_key_R; theta] plus each robot's open segment.

    ``initial_pose`` (3,) for one robot, (R, 3) for a fleet; the methods that touch a key
    pose take the ``robot`` (0 .. R-1) whose key block they use.
    """

    def __init__(self, sensor: SensorConfig, initial_pose, initial_pose_std,
                 first_estimates: bool = True, relinearize_threshold: float = np.inf, iterations: int = 1) -> None:
        # iterations: the base's segment_poses offers none here (EMConfig allows 1 only).
        super().__init__(sensor, initial_pose, first_estimates, relinearize_threshold, iterations)
        std = np.maximum(np.asarray(initial_pose_std, dtype=float), MIN_PRIOR_STD)
        self._pending = 0                       # landmarks added, not yet in _info / _vector
        self.info = np.zeros((self.key_dim, self.key_dim))                      # (3R + 2M, 3R + 2M)
        for r in range(self.key_poses.shape[0]):
            self.info[self._key(r), self._key(r)] = np.diag(1.0 / std ** 2)
        self.vector = np.zeros(self.key_dim)                                    # (3R + 2M,)
        self._covariance_cache: np.ndarray | None = None
        # The last solve's Cholesky factor, until the system changes but for pruning, which keeps
        # the others' Gaussian: _solved_rows are the landmark rows of the factor (covariances_given_key).
        self._solved, self._solved_rows = None, np.zeros(0, dtype=np.int64)

    # The system grows by zero rows for each new landmark.  Growing is a copy of the whole
    # matrix, O(M^2), and a map that grows by two landmarks a step paid it at every step (27 %
    # of a step at M = 1000); so new landmarks are counted and enter at the next use, at once.
    @property
    def info(self) -> np.ndarray:
        self._grow()
        return self._info

    @info.setter
    def info(self, value: np.ndarray) -> None:
        self._info = value

    @property
    def vector(self) -> np.ndarray:
        self._grow()
        return self._vector

    @vector.setter
    def vector(self, value: np.ndarray) -> None:
        self._vector = value

    def _grow(self) -> None:
        if self._pending:
            n, extra = self._info.shape[0], 2 * self._pending
            self._pending = 0
            info = np.zeros((n + extra, n + extra))
            info[:n, :n] = self._info
            self._info = info
            self._vector = np.concatenate([self._vector, np.zeros(extra)])

    @property
    def n_landmarks(self) -> int:
        return (self._info.shape[0] - self.key_dim) // 2 + self._pending

    # ------------------------------------------------------------ map rows
    def add_landmarks(self, count: int) -> None:
        """New landmarks enter with zero information; their factors bring it."""
        if count <= 0:
            return
        self._pending += count
        self._add_landmark_rows(count)
        self._covariance_cache = None

    def keep_landmarks(self, keep: np.ndarray) -> None:
        """Remove landmarks (``keep`` False) by integrating them out (Schur complement).

        Marginalising, not deleting, leaves the other landmarks' solution exactly unchanged.
        """
        keep = np.asarray(keep, dtype=bool)
        self._keep_landmark_rows(keep)
        if keep.all():
            return
        self._solved_rows = self._solved_rows[keep[:self._solved_rows.size]]
        lm = np.arange(self.key_dim, self.info.shape[0]).reshape(-1, 2)
        kept = np.concatenate([np.arange(self.key_dim), lm[keep].ravel()])
        dropped = lm[~keep].ravel()
        self.info, self.vector = marginalize(self.info, self.vector, kept, dropped)
        self._covariance_cache = None

    # ------------------------------------------------------------ factors
    def fold(self, segment: SegmentSystem, robot: int = 0) -> None:
        """Add ``segment``'s factor against ``robot``'s key block and integrate out its key and
        every pose but the last, which becomes the key.  Built at another key point (another
        node's, :meth:`move_key` moves them apart), the factor is re-expressed exactly first."""
        shift = segment.key - self.key_poses[robot]
        if np.any(shift):
            self.move_key(shift, robot)
        local, local_vector, seen, k = segment.local.copy(), segment.vector.copy(), segment.seen, segment.steps
        key = self._key(robot)
        local[:POSE_DIM, :POSE_DIM] += self.info[key, key]
        local_vector[:POSE_DIM] += self.vector[key]
        lm = self.key_dim + 2 * seen[:, None] + np.arange(2)
        small = np.concatenate([np.arange(POSE_DIM), lm.ravel()])      # x_K, theta_S in the new system
        order = np.r_[np.arange(key.start, key.stop), np.arange(key.start), np.arange(key.stop, self.vector.size)]
        info, vector = (self.info, self.vector) if robot == 0 else (self.info[np.ix_(order, order)], self.vector[order])
        info, vector = segment_schur(info, vector, local, local_vector, POSE_DIM * k, small)
        if robot != 0:                                                 # back to [key_1 .. key_R; theta]
            self.info[np.ix_(order, order)], self.vector[order] = info, vector
        else:
            self.info, self.vector = info, vector
        self._key_point_set(segment.pose, robot)
        self._covariance_cache = self._solved = None

    # ------------------------------------------------------------ solve
    def solve(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Minimiser of the stored quadratic: (theta (M, 2), dx_keys (3R,): robot r's key
        correction at [3r, 3r + 3)), None if not positive definite."""
        factor = self._solved = self._factor()
        if factor is None:
            return None
        self._solved_rows = np.arange(self.n_landmarks)
        z = cho_solve(factor, self.vector)
        if not np.all(np.isfinite(z)):
            return None
        return z[self.key_dim:].reshape(-1, 2), z[:self.key_dim]

    def move_key(self, shift: np.ndarray, robot: int = 0) -> None:
        """Re-express the system after ``robot``'s key pose linearisation point moved by ``shift``:
        dx_old = dx_new + shift, so the vector loses info[:, key] shift."""
        self.vector = self.vector - self.info[:, self._key(robot)] @ shift
        self._key_point_moved(shift, robot)

    def restart_key(self, pose: np.ndarray, pose_std, robot: int = 0) -> None:
        """The robot was put at ``pose`` (an initial-pose message, a relocalisation):
        no motion links it to the old key pose, which is integrated out; the new key
        pose enters with the prior N(pose, diag(pose_std)^2) and no tie to the map
        (nor to the other robots' key poses)."""
        if self.segments[robot]:
            raise RuntimeError("close the segment before restarting the key pose")
        n = self.info.shape[0]
        key = np.arange(self._key(robot).start, self._key(robot).stop)
        rest = np.setdiff1d(np.arange(n), key)
        marginal, marginal_vector = marginalize(self.info, self.vector, rest, key)
        std = np.maximum(np.asarray(pose_std, dtype=float), MIN_PRIOR_STD)
        self.info = np.zeros((n, n))
        self.info[np.ix_(key, key)] = np.diag(1.0 / std ** 2)
        self.info[np.ix_(rest, rest)] = marginal
        self.vector = np.zeros(n)
        self.vector[rest] = marginal_vector
        self._key_point_set(pose, robot)
        self._covariance_cache = self._solved = None

    def add_prior(self, rows: np.ndarray, theta: np.ndarray, A: np.ndarray) -> None:
        """Independent priors N(theta, A^-1) on landmarks ``rows`` (a loaded map): A (k, 2, 2)."""
        lm = self.key_dim + 2 * np.asarray(rows)[:, None] + np.arange(2)
        self.info[lm[:, :, None], lm[:, None, :]] += A
        self.vector[lm] += np.einsum("mij,mj->mi", A, theta)
        self._covariance_cache = self._solved = None

    def landmark_covariances(self) -> np.ndarray | None:
        """Marginal covariances (M, 2, 2) of the map: diagonal blocks of info^-1."""
        if self._covariance_cache is None:
            factor = self._factor()
            if factor is None:
                return None
            inverse = cho_solve(factor, np.eye(self.info.shape[0]))
            lm = np.arange(self.key_dim, self.info.shape[0]).reshape(-1, 2)
            self._covariance_cache = inverse[lm[:, :, None], lm[:, None, :]]
        return self._covariance_cache

    def covariances_given_key(self, rows: np.ndarray, robot: int = 0) -> np.ndarray:
        """(P, 2, 2) each landmark of ``rows``' covariance given ``robot``'s key pose, from the last
        solve's factor; NaN for landmarks that came after it (and for all when it failed)."""
        out = np.full((len(rows), 2, 2), np.nan)
        rows = np.asarray(rows)
        known = (rows < self._solved_rows.size) if self._solved is not None else np.zeros(rows.size, dtype=bool)
        if known.any():
            key, n = self._key(robot), self._solved[0].shape[0]
            lm = self.key_dim + 2 * self._solved_rows[rows[known]][:, None] + np.arange(2)
            idx = np.concatenate([np.arange(key.start, key.stop), lm.ravel()])
            unit = np.zeros((n, idx.size))
            unit[idx, np.arange(idx.size)] = 1.0
            S = cho_solve(self._solved, unit)[idx]
            pairs = POSE_DIM + np.arange(2 * known.sum()).reshape(-1, 2)
            out[known] = given_key(S[:POSE_DIM, :POSE_DIM], S[pairs, :POSE_DIM],
                                   S[pairs[:, :, None], pairs[:, None, :]])
        return out

    def _factor(self):
        try:
            return cho_factor(self.info, lower=True, check_finite=True)
        except (LinAlgError, ValueError):
            return None


def segment_schur(info: np.ndarray, vector: np.ndarray, local: np.ndarray, local_vector: np.ndarray,
                  n_eliminated: int, small: np.ndarray):
    """The stored system over [x_K; theta] after integrating out e = [key, x_1..x_{K-1}].

    ``info``/``vector``: stored system over [key; theta]; ``local``: the segment's
    factors (plus the stored key block) over [e, x_K, theta_S]; ``small``: where
    x_K and theta_S sit in the result.  With B_ee = local[e, e], P the stored
    key-map coupling and Q = local[e, small]:
        B_re B_ee^-1 B_er = P^T M P + P^T N Q + Q^T N^T P + Q^T B_ee^-1 Q,
    M = (B_ee^-1)[key, key], N = (B_ee^-1 Q)[key]: a rank-3 update of the whole
    map block and small blocks on x_K and theta_S.
    """
    e = n_eliminated
    B_ee, Q = local[:e, :e], local[:e, e:]
    rhs = np.zeros((e, POSE_DIM + Q.shape[1] + 1))
    rhs[:POSE_DIM, :POSE_DIM] = np.eye(POSE_DIM)
    rhs[:, POSE_DIM:-1] = Q
    rhs[:, -1] = local_vector[:e]
    try:
        W = cho_solve(cho_factor(B_ee, lower=True), rhs)
    except LinAlgError:
        W = np.linalg.lstsq(B_ee, rhs, rcond=None)[0]
    M, N, w = W[:POSE_DIM, :POSE_DIM], W[:POSE_DIM, POSE_DIM:-1], W[:, -1]
    M = 0.5 * (M + M.T)
    P = info[:POSE_DIM].copy()
    P[:, :POSE_DIM] = 0.0                                    # the new x_K has no stored coupling
    PtM = P.T @ M
    new = info.copy()
    new[:POSE_DIM], new[:, :POSE_DIM] = 0.0, 0.0
    new -= PtM @ P
    cross = P.T @ N                                          # (3 + 2M, n_small)
    new[:, small] -= cross
    new[small] -= cross.T
    new[np.ix_(small, small)] += local[e:, e:] - Q.T @ W[:, POSE_DIM:-1]
    new_vector = vector.copy()
    new_vector[:POSE_DIM] = 0.0
    new_vector -= P.T @ w[:POSE_DIM]
    new_vector[small] += local_vector[e:] - Q.T @ w
    return new, new_vector


