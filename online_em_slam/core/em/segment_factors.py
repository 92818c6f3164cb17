"""The observed M-step's factors, and the Gaussian of the map they build.

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

The stored Gaussian is over z = [dx_key; theta], dx_key the correction of the latest
kept pose: its size grows with the map, never with time.  A fleet (core/fleet/) stores R
key poses, z = [dx_key_1 .. dx_key_R; theta], and each robot's segments are closed against
its own key block; R = 1 is the single robot.  The factors of a segment of K filter steps
are buffered (this module), linearised at the segment's end (so a landmark that moved
during the segment is linearised where it is now), and all the segment's poses but its
last are integrated out.  Two stores hold the same Gaussian: in information form
(observed_information.py: a Cholesky solve per segment, O(M^3)) and in covariance form
(observed_covariance.py: mean and covariance updated in O(M^2) per segment).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ..config import SensorConfig
from ..models.angles import wrap_angle
from ..models.gaussian import symmetric_inverse_3x3
from ..models.observation import innovation, landmark_jacobian, pose_jacobian, predict_observation, sensor_poses

POSE_DIM = 3
# A segment's Gauss-Newton iterations stop once no pose moves by more than this (m, rad).
ITERATION_TOLERANCE = np.array([1e-4, 1e-4, 1e-5])
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
    (the stores' ``fold`` re-expresses it)."""

    local: np.ndarray
    vector: np.ndarray
    key: np.ndarray
    pose: np.ndarray
    seen: np.ndarray
    counts: np.ndarray      # (S,) observations of each landmark in the segment

    @property
    def steps(self) -> int:
        return (self.local.shape[0] - 2 * self.seen.size) // POSE_DIM - 1


class SegmentFactors:
    """Each robot's buffered step factors and the points they are linearised at.

    ``initial_pose`` (3,) for one robot, (R, 3) for a fleet; the methods that touch a key
    pose take the ``robot`` (0 .. R-1) whose key block they use.  A store (information or
    covariance form) adds ``fold``, ``solve``, ``move_key``, ``restart_key``,
    ``keep_landmarks``, ``landmark_covariances`` and ``add_prior``.
    """

    def __init__(self, sensor: SensorConfig, initial_pose, first_estimates: bool = True,
                 relinearize_threshold: float = np.inf, iterations: int = 1) -> None:
        self.sensor = sensor
        self.first_estimates = first_estimates
        self.relinearize_threshold = relinearize_threshold
        self.iterations = iterations
        self.key_poses = np.asarray(initial_pose, dtype=float).reshape(-1, POSE_DIM).copy()   # xbar of each key
        self.key_firsts = self.key_poses.copy()                                 # their first estimates
        self.key_dim = POSE_DIM * self.key_poses.shape[0]                       # where theta starts
        self.landmark_first = np.zeros((0, 2))                                  # NaN until first linearised
        self.segments: list[list[StepFactors]] = [[] for _ in range(self.key_poses.shape[0])]

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
    def _add_landmark_rows(self, count: int) -> None:
        self.landmark_first = np.vstack([self.landmark_first, np.full((count, 2), np.nan)])

    def _keep_landmark_rows(self, keep: np.ndarray) -> None:
        """The rows ``keep`` says stay; buffered factors of a removed landmark are dropped: it
        has not reached the stored Gaussian yet, and one or two observations of a free landmark
        say next to nothing about the poses."""
        self.landmark_first = self.landmark_first[keep]
        new_row = np.cumsum(keep) - 1
        for step in (step for segment in self.segments for step in segment):
            mask = keep[step.rows]
            step.rows, step.y, step.precision = new_row[step.rows[mask]], step.y[mask], step.precision[mask]

    # ------------------------------------------------------------ key points
    def _key_point_moved(self, shift: np.ndarray, robot: int) -> None:
        self.key_poses[robot] = self.key_poses[robot] + shift
        if np.hypot(shift[0], shift[1]) > self.relinearize_threshold:
            # After a large correction (a loop closure) the first estimate would put
            # the whole shift into the next motion factor's yaw lever.
            self.key_firsts[robot] = self.key_poses[robot]

    def _key_point_set(self, pose: np.ndarray, robot: int) -> None:
        self.key_poses[robot] = np.asarray(pose, dtype=float)
        self.key_firsts[robot] = self.key_poses[robot]

    # ------------------------------------------------------------ factors
    def add_step(self, step: StepFactors, robot: int = 0) -> None:
        self.segments[robot].append(step)

    def close_segment(self, theta: np.ndarray, robot: int = 0) -> SegmentSystem | None:
        """Linearise ``robot``'s buffered factors at (xbar_t, theta) and integrate out every
        pose of its segment but the last, which becomes its key pose; the segment's factor
        (:meth:`segment_system`, None without a segment), e.g. to send to other nodes.

        The segment's poses see only the landmarks S observed in it: its factors go into a
        small system over [key, x_1..x_K, theta_S] (:meth:`segment_system`), which the store
        folds into the stored Gaussian (``fold``).  With ``iterations`` > 1 the segment's
        poses and landmarks are first relinearised at the solution (:meth:`_iterate`); the
        key then moves back to the filter's pose, which the returned correction is relative to.
        """
        if not self.segments[robot]:
            return None
        filter_pose = self.segments[robot][-1].pose.copy()
        segment = self.segment_system(self._iterate(theta, robot), robot)
        self.fold(segment, robot)
        shift = filter_pose - segment.pose
        if np.any(shift):
            self.move_key(shift, robot)
        return segment

    def _iterate(self, theta: np.ndarray, robot: int) -> np.ndarray:
        """Gauss-Newton on the segment under the stored Gaussian's prior: each iteration solves
        the segment (the store's ``segment_solution``) and relinearises its poses and landmarks
        at the solution, until no pose moves by ITERATION_TOLERANCE; the map the segment is
        then closed at (``theta`` with the segment's landmarks moved).  A landmark's first
        estimate (FEJ) is taken at that close, not at an iteration's point."""
        first = self.landmark_first.copy()
        for _ in range(self.iterations - 1):
            segment = self._linearised(theta, robot)
            solution = self.segment_solution(segment, robot)
            if solution is None:
                break
            dx, theta_seen = solution
            self._relinearise_steps(dx, robot)
            theta = theta.copy()
            theta[segment.seen] = theta_seen
            if np.all(np.abs(dx) <= ITERATION_TOLERANCE):
                break
        self.landmark_first = first
        return theta

    def segment_solution(self, segment: SegmentSystem, robot: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The segment's pose corrections dx_1..dx_K (K, 3) and landmarks theta_S (S, 2) under
        the stored prior; None: no iteration (a store that does not offer it)."""
        return None

    def _relinearise_steps(self, dx: np.ndarray, robot: int) -> None:
        """Each buffered step's point xbar_t moved by dx_t (K, 3), its motion factor with it.

        Every motion model moves a pose through its heading only: f(x, u) = x + A(phi) m(u),
        A the rotation of the position.  So at x_{t-1} turned by d, f's move, F's lever and
        Q's position block turn by d (F = I + s e_yaw^T: A F A^T = I + (A s) e_yaw^T)."""
        segment = self.segments[robot]
        old_previous = new_previous = self.key_poses[robot]
        for t, step in enumerate(segment):
            pose = step.pose + dx[t]
            A = _yaw_rotation(new_previous[2] - old_previous[2])
            predicted = new_previous + A @ (step.c + step.pose - old_previous)
            segment[t] = replace(step, pose=pose, c=motion_residual(predicted, pose), F=A @ step.F @ A.T,
                                 Q=A @ step.Q @ A.T)
            old_previous, new_previous = step.pose, pose

    def segment_system(self, theta: np.ndarray, robot: int = 0) -> SegmentSystem | None:
        """``robot``'s buffered factors linearised at (xbar_t, theta) as one factor; the buffer empties."""
        if not self.segments[robot]:
            return None
        system = self._linearised(theta, robot)
        self.segments[robot] = []
        return system

    def _linearised(self, theta: np.ndarray, robot: int) -> SegmentSystem:
        """``robot``'s buffered factors linearised at (xbar_t, theta) as one factor."""
        segment = self.segments[robot]
        seen, counts = np.unique(np.concatenate([s.rows for s in segment]), return_counts=True)
        n_pose = POSE_DIM * (len(segment) + 1)
        local = np.zeros((n_pose + 2 * seen.size,) * 2)
        local_vector = np.zeros(local.shape[0])
        self._add_motion_factors(local, local_vector, robot)
        self._add_observation_factors(local, local_vector, theta, n_pose, seen, robot)
        return SegmentSystem(local, local_vector, self.key_poses[robot].copy(), segment[-1].pose.copy(), seen, counts)

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


def _yaw_rotation(angle: float) -> np.ndarray:
    """(3, 3): the position turned by ``angle``, the yaw kept."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


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


def given_key(S_kk: np.ndarray, S_lk: np.ndarray, S_ll: np.ndarray) -> np.ndarray:
    """Landmarks' covariances given a key pose, S_ll - S_lk S_kk^-1 S_kl (P, 2, 2), from the joint
    Gaussian's blocks S_kk (3, 3), S_lk (P, 2, 3), S_ll (P, 2, 2)."""
    S_lk_over_S_kk = np.linalg.solve(S_kk, S_lk.reshape(-1, POSE_DIM).T).T.reshape(S_lk.shape)    # one solve
    out = S_ll - S_lk_over_S_kk @ np.swapaxes(S_lk, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))
