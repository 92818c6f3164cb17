"""Observed information of the map: the joint Gauss-Newton system with the poses integrated out.

docs/METHOD.md, "Observed-information M-step".  Under the
seed's local linearisation, the log-likelihood of the map is, to second order,
what remains of the joint least-squares problem over (poses, map) once the
poses are integrated out (a Schur complement).  Its curvature is the *observed*
information (Louis 1982: complete minus missing information), so a Newton step
with it moves the whole map at a loop closure, where the complete-data M-step
theta_k = A_k^-1 b_k leaves a drifted map as a near fixed point.

Variables: dx_t = X_t - xbar_t, the correction of pose t from its linearisation
point (the filter's weighted mean pose), and theta, the map in absolute
coordinates.  Factors, each a linear residual r = target - J z with information W:

    prior        r = (x_0 - xbar_0) - dx_0,                    W = P_0^-1        (P)
    motion       r = c_t - (dx_t - F_t dx_{t-1}),              W = Q_t^-1        (M)
                 c_t = f(xbar_{t-1}, u_t) - xbar_t (yaw wrapped)
    observation  r = (ytilde + H_l thetabar_k) - (H_x dx_t + H_l theta_k),
                 ytilde = y - h(xbar_t, thetabar_k) (bearing wrapped),  W = Pbar  (O)

The stored system is the information matrix and vector over z = [dx_key; theta],
dx_key the correction of the latest kept pose: its size grows with the map,
never with time.  A fleet (core/fleet/) stores R key poses, z = [dx_key_1 ..
dx_key_R; theta], and each robot's segments are closed against its own key block;
R = 1 is the single robot.  The factors of a segment of K filter steps are buffered,
linearised at the segment's end (so a landmark that moved during the segment
is linearised where it is now), and all the segment's poses but its last are
integrated out.  With one segment and no map update in between, the solve is
exactly one Gauss-Newton step of batch least squares over every pose and
landmark (test_observed_information.py checks this against scipy).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ..models.angles import wrap_angle
from ..models.gaussian import symmetric_inverse_3x3
from ..config import SensorConfig
from ..models.observation import innovation, landmark_jacobian, pose_jacobian, predict_observation, sensor_poses

POSE_DIM = 3
# Floors of the first-pose prior: a start known exactly still needs a finite
# information to pin the gauge (the map's frame).
MIN_PRIOR_STD = np.array([1e-3, 1e-3, 1e-4])


@dataclass
class StepFactors:
    """The factors one filter step adds: motion from the previous pose, observations at this pose.

    pose (3,) linearisation point xbar_t; F (3, 3), c (3,) and Q (3, 3) of (M), whose information
    W = Q^-1 the segment's close takes for all its steps at once;
    rows (P,) landmark rows, y (P, 2) observations, precision (P, 2, 2) Pbar of (O).
    """

    pose: np.ndarray
    F: np.ndarray
    c: np.ndarray
    Q: np.ndarray
    rows: np.ndarray
    y: np.ndarray
    precision: np.ndarray


@dataclass
class SegmentSystem:
    """A robot's segment as one factor, before it is folded into the stored system.

    ``local`` (n, n) and ``vector`` (n,): the segment's motion and observation factors over
    [dx_key, dx_1 .. dx_K, theta_S], n = 3 (K + 1) + 2 S, without the stored key block;
    ``key`` (3,) the key pose's linearisation point they were built at, ``pose`` (3,) x_K's
    (the next key), ``seen`` (S,) the rows of theta_S.  The landmarks are in absolute
    coordinates, so the factor holds for any map estimate; only the key's point matters
    (ObservedInformation.fold re-expresses it)."""

    local: np.ndarray
    vector: np.ndarray
    key: np.ndarray
    pose: np.ndarray
    seen: np.ndarray
    counts: np.ndarray      # (S,) observations of each landmark in the segment

    @property
    def steps(self) -> int:
        return (self.local.shape[0] - 2 * self.seen.size) // POSE_DIM - 1


class ObservedInformation:
    """Information form over [dx_key_1 .. dx_key_R; theta] plus each robot's open segment.

    ``initial_pose`` (3,) for one robot, (R, 3) for a fleet; the methods that touch a key
    pose take the ``robot`` (0 .. R-1) whose key block they use.
    """

    def __init__(self, sensor: SensorConfig, initial_pose, initial_pose_std,
                 first_estimates: bool = True, relinearize_threshold: float = np.inf) -> None:
        self.sensor = sensor
        self.first_estimates = first_estimates
        self.relinearize_threshold = relinearize_threshold
        std = np.maximum(np.asarray(initial_pose_std, dtype=float), MIN_PRIOR_STD)
        self.key_poses = np.asarray(initial_pose, dtype=float).reshape(-1, POSE_DIM).copy()   # xbar of each key
        self.key_firsts = self.key_poses.copy()                                 # their first estimates
        self.key_dim = POSE_DIM * self.key_poses.shape[0]                       # where theta starts
        self.landmark_first = np.zeros((0, 2))                                  # NaN until first linearised
        self._pending = 0                       # landmarks added, not yet in _info / _vector
        self.info = np.zeros((self.key_dim, self.key_dim))                      # (3R + 2M, 3R + 2M)
        for r in range(self.key_poses.shape[0]):
            self.info[self._key(r), self._key(r)] = np.diag(1.0 / std ** 2)
        self.vector = np.zeros(self.key_dim)                                    # (3R + 2M,)
        self.segments: list[list[StepFactors]] = [[] for _ in range(self.key_poses.shape[0])]
        self._covariance_cache: np.ndarray | None = None

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

    @property
    def key_pose(self) -> np.ndarray:
        """Robot 0's key pose xbar (the single robot's)."""
        return self.key_poses[0]

    @property
    def key_first(self) -> np.ndarray:
        return self.key_firsts[0]

    @property
    def segment(self) -> list[StepFactors]:
        """Robot 0's open segment."""
        return self.segments[0]

    @staticmethod
    def _key(robot: int) -> slice:
        """Robot ``robot``'s key block in z."""
        return slice(POSE_DIM * robot, POSE_DIM * (robot + 1))

    # ------------------------------------------------------------ map rows
    def add_landmarks(self, count: int) -> None:
        """New landmarks enter with zero information; their factors bring it."""
        if count <= 0:
            return
        self._pending += count
        self.landmark_first = np.vstack([self.landmark_first, np.full((count, 2), np.nan)])
        self._covariance_cache = None

    def keep_landmarks(self, keep: np.ndarray) -> None:
        """Remove landmarks (``keep`` False) by integrating them out (Schur complement).

        Marginalising, not deleting, leaves the other landmarks' solution exactly
        unchanged.  Buffered factors of a removed landmark are dropped: it has not
        reached the stored system yet, and one or two observations of a free
        landmark say next to nothing about the poses.
        """
        keep = np.asarray(keep, dtype=bool)
        self.landmark_first = self.landmark_first[keep]
        new_row = np.cumsum(keep) - 1
        for step in (step for segment in self.segments for step in segment):
            mask = keep[step.rows]
            step.rows, step.y, step.precision = new_row[step.rows[mask]], step.y[mask], step.precision[mask]
        if keep.all():
            return
        lm = np.arange(self.key_dim, self.info.shape[0]).reshape(-1, 2)
        kept = np.concatenate([np.arange(self.key_dim), lm[keep].ravel()])
        dropped = lm[~keep].ravel()
        self.info, self.vector = marginalize(self.info, self.vector, kept, dropped)
        self._covariance_cache = None

    # ------------------------------------------------------------ factors
    def add_step(self, step: StepFactors, robot: int = 0) -> None:
        self.segments[robot].append(step)

    def close_segment(self, theta: np.ndarray, robot: int = 0) -> SegmentSystem | None:
        """Linearise ``robot``'s buffered factors at (xbar_t, theta) and integrate out every
        pose of its segment but the last, which becomes its key pose; the segment's factor
        (:meth:`segment_system`, None without a segment), e.g. to send to other nodes.

        Only the old key pose couples to the whole map, and the segment's poses see
        only the landmarks S observed in it: the factors go into a small system over
        [key, x_1..x_K, theta_S]; integrating [key, x_1..x_{K-1}] out changes the
        stored map block by a rank-3 term plus terms on x_K and theta_S
        (:func:`segment_schur`), O(M^2) with a small constant, not O((M + K)^3).
        In a fleet the system is reordered so that the robot's key block comes first
        (the other keys then sit with the map) and put back in order afterwards.
        """
        segment = self.segment_system(theta, robot)
        if segment is not None:
            self.fold(segment, robot)
        return segment

    def segment_system(self, theta: np.ndarray, robot: int = 0) -> SegmentSystem | None:
        """``robot``'s buffered factors linearised at (xbar_t, theta) as one factor; the buffer empties."""
        segment = self.segments[robot]
        if not segment:
            return None
        seen, counts = np.unique(np.concatenate([s.rows for s in segment]), return_counts=True)
        n_pose = POSE_DIM * (len(segment) + 1)
        local = np.zeros((n_pose + 2 * seen.size,) * 2)
        local_vector = np.zeros(local.shape[0])
        self._add_motion_factors(local, local_vector, robot)
        self._add_observation_factors(local, local_vector, theta, n_pose, seen, robot)
        self.segments[robot] = []
        return SegmentSystem(local, local_vector, self.key_poses[robot].copy(), segment[-1].pose.copy(), seen, counts)

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
        self.key_poses[robot] = segment.pose
        self.key_firsts[robot] = segment.pose
        self._covariance_cache = None

    def _add_motion_factors(self, info: np.ndarray, vector: np.ndarray, robot: int) -> None:
        """(M) for every step: J = [-F_t, I] on (dx_{t-1}, dx_t).

        With first-estimate Jacobians, F's yaw column is the displacement between
        the two poses' first estimates, perp(p_t - p_{t-1}), instead of the model's
        perp(f(xbar_{t-1}) - xbar_{t-1}): then a rotation of every pose and
        landmark stays in the null space of every factor (FEJ, Huang, Mourikis &
        Roumeliotis 2008), and the linearised system gains no false information
        about the map's orientation, which nothing but the first pose observes.
        """
        segment = self.segments[robot]
        F = np.stack([s.F for s in segment])                                 # (K, 3, 3)
        if self.first_estimates:
            firsts = np.stack([self.key_firsts[robot]] + [s.pose for s in segment])
            step = np.diff(firsts[:, :2], axis=0)
            F = F.copy()
            F[:, 0, 2], F[:, 1, 2] = -step[:, 1], step[:, 0]
        W = symmetric_inverse_3x3(np.stack([s.Q for s in segment]))[0]
        c = np.stack([s.c for s in segment])
        J = np.concatenate([-F, np.broadcast_to(np.eye(POSE_DIM), F.shape)], axis=-1)   # (K, 3, 6)
        index = POSE_DIM * np.arange(len(segment))[:, None] + np.arange(2 * POSE_DIM)
        _scatter(info, vector, index, J, W, c)

    def _add_observation_factors(self, info, vector, theta, first_landmark: int, seen: np.ndarray,
                                 robot: int) -> None:
        """(O) for every observation: J = [H_x, H_l] on (dx_t, theta_k); landmark k sits
        at ``first_landmark + 2 * (its position in seen)``."""
        steps = [(t, s) for t, s in enumerate(self.segments[robot], start=1) if s.rows.size]
        if not steps:
            return
        step_of = np.concatenate([np.full(s.rows.size, t) for t, s in steps])
        poses = np.stack([s.pose for _, s in steps])[np.repeat(np.arange(len(steps)), [s.rows.size for _, s in steps])]
        rows = np.concatenate([s.rows for _, s in steps])
        y = np.concatenate([s.y for _, s in steps])
        precision = np.concatenate([s.precision for _, s in steps])
        J, target = observation_factor(poses, self._linearisation_points(theta)[rows], y, self.sensor,
                                       now=theta[rows])
        index = np.concatenate([POSE_DIM * step_of[:, None] + np.arange(POSE_DIM),
                                first_landmark + 2 * np.searchsorted(seen, rows)[:, None] + np.arange(2)],
                               axis=1)
        _scatter(info, vector, index, J, precision, target)

    def _linearisation_points(self, theta: np.ndarray) -> np.ndarray:
        """Where each landmark's Jacobians are taken: its first estimate (FEJ), renewed
        when the landmark has moved farther than ``relinearize_threshold`` from it;
        the current estimate without first-estimate Jacobians."""
        if not self.first_estimates:
            return theta
        first = self.landmark_first
        renew = np.isnan(first[:, 0]) | (np.linalg.norm(theta - first, axis=1) > self.relinearize_threshold)
        first[renew] = theta[renew]
        return first

    # ------------------------------------------------------------ solve
    def solve(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Minimiser of the stored quadratic: (theta (M, 2), dx_keys (3R,): robot r's key
        correction at [3r, 3r + 3)), None if not positive definite."""
        factor = self._factor()
        if factor is None:
            return None
        z = cho_solve(factor, self.vector)
        if not np.all(np.isfinite(z)):
            return None
        return z[self.key_dim:].reshape(-1, 2), z[:self.key_dim]

    def move_key(self, shift: np.ndarray, robot: int = 0) -> None:
        """Re-express the system after ``robot``'s key pose linearisation point moved by ``shift``:
        dx_old = dx_new + shift, so the vector loses info[:, key] shift."""
        self.vector = self.vector - self.info[:, self._key(robot)] @ shift
        self.key_poses[robot] = self.key_poses[robot] + shift
        if np.hypot(shift[0], shift[1]) > self.relinearize_threshold:
            # After a large correction (a loop closure) the first estimate would put
            # the whole shift into the next motion factor's yaw lever.
            self.key_firsts[robot] = self.key_poses[robot]

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
        self.key_poses[robot] = np.asarray(pose, dtype=float)
        self.key_firsts[robot] = self.key_poses[robot]
        self._covariance_cache = None

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

    def _factor(self):
        try:
            return cho_factor(self.info, lower=True, check_finite=True)
        except (LinAlgError, ValueError):
            return None


def observation_factor(poses: np.ndarray, landmarks: np.ndarray, y: np.ndarray, sensor: SensorConfig,
                       now: np.ndarray | None = None):
    """J (P, 2, 5) = [H_x, H_l] and target (P, 2) = ytilde + H_l thetabar of (O).

    Jacobians at ``landmarks``; the residual ytilde and thetabar at ``now``
    (default the same points), so first-estimate Jacobians keep current residuals.
    """
    now = landmarks if now is None else now
    sensor_pose = sensor_poses(poses, sensor)
    ytilde = innovation(y.copy(), predict_observation(sensor_pose, now))
    H_l = landmark_jacobian(sensor_pose, landmarks)
    H_x = pose_jacobian(poses, landmarks, sensor)
    target = ytilde + np.einsum("pij,pj->pi", H_l, now)
    return np.concatenate([H_x, H_l], axis=-1), target


def motion_residual(predicted: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """c_t = f(xbar_{t-1}, u) - xbar_t, yaw wrapped: what the observations moved the pose by."""
    c = predicted - pose
    c[2] = wrap_angle(c[2])
    return c


def _scatter(info: np.ndarray, vector: np.ndarray, index: np.ndarray, J: np.ndarray,
             W: np.ndarray, target: np.ndarray) -> None:
    """info[idx, idx] += J^T W J and vector[idx] += J^T W target for every factor (vectorised)."""
    JtW = np.swapaxes(J, -1, -2) @ W
    np.add.at(info, (index[:, :, None], index[:, None, :]), JtW @ J)
    np.add.at(vector, index, np.einsum("fij,fj->fi", JtW, target))


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


def marginalize(info: np.ndarray, vector: np.ndarray, kept: np.ndarray, eliminated: np.ndarray):
    """Integrate the ``eliminated`` variables out of the information form (Schur complement)."""
    if eliminated.size == 0:
        return info.take(kept, 0).take(kept, 1), vector[kept]
    L_ee = info[np.ix_(eliminated, eliminated)]
    L_ek = info[np.ix_(eliminated, kept)]
    try:
        factor = cho_factor(L_ee, lower=True)
        X = cho_solve(factor, np.column_stack([L_ek, vector[eliminated]]))
    except LinAlgError:
        X = np.linalg.lstsq(L_ee, np.column_stack([L_ek, vector[eliminated]]), rcond=None)[0]
    # take() and the in-place sums are the same arithmetic as fancy indexing and 0.5 * (S + S^T),
    # with fewer passes over an O(M^2) matrix (at M = 1000 this ran once per pruned landmark).
    schur = info.take(kept, 0).take(kept, 1)
    schur -= L_ek.T @ X[:, :-1]
    symmetric = schur.T.copy()
    symmetric += schur
    symmetric *= 0.5
    return symmetric, vector[kept] - L_ek.T @ X[:, -1]
