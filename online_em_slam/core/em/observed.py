"""The observed-information M-step: a Newton step of the map with the poses integrated out.

docs/METHOD.md, "Observed-information M-step".  The particle filter stays the E-step:
it supplies the weighted mean pose xbar_t (the linearisation point), the
association and the mixture responsibilities.  Each filter step adds its
motion and observation factors to the map's Gaussian (``em.map_form``: covariance,
observed_covariance.ObservedCovariance, or information, observed_information.ObservedInformation);
every ``em.segment_length`` steps the segment's poses are integrated out and
the map is solved (online EM) or, with Block Online EM, solved at block ends
only, theta staying fixed inside a block.  The solve also gives the correction
of the current pose under the new map, which the filter applies to its
particles so that the next factors are linearised where the pose now is.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import SlamConfig
from .step import FilterStepData
from ..mapping.landmarks import LandmarkTable
from ..models.observation import inv_det_2x2, landmark_jacobian, sensor_poses
from .merge import MAX_MERGES, DuplicateMerger
from .observed_covariance import ObservedCovariance
from .observed_information import ObservedInformation
from .segment_factors import POSE_DIM, StepFactors, motion_residual
from .segment_message import SegmentMessage
from .statistics import STAT_DIM, unpack

# Under heavy-tailed noise a landmark's first observation cannot be checked against anything:
# it places the landmark with the weight of a diffuse prior (R x 1000) and the later, checked
# observations carry the estimate.  At full weight a first observation that is an outlier held
# the landmark there, the true observations judged outliers against it (docs/RESULTS.md).
FIRST_OBSERVATION_WEIGHT = 1e-3


class ObservedInformationEM:
    """Segments of K filter steps; the map solved from the joint information at segment ends.

    ``initial_pose`` (3,) for one robot; (R, 3) for a fleet (core/fleet/), whose robots
    pass their index to :meth:`update` and :meth:`restart_pose`.
    """

    def __init__(self, config: SlamConfig, initial_pose: np.ndarray) -> None:
        self.config = config
        store = ObservedCovariance if config.em.map_form == "covariance" else ObservedInformation
        single = np.ndim(initial_pose) == 1
        # The fixed lag (em.segment_iterations) is measured for one robot; a fleet folds once.
        self.system = store(config.sensor, initial_pose, config.filter.initial_pose_std,
                            first_estimates=config.em.first_estimate_jacobians,
                            relinearize_threshold=config.em.relinearize_threshold,
                            iterations=config.em.segment_iterations if single else 1)
        # Complete-data information per landmark, sum of H^T Pbar H: its inverse is the
        # landmark's uncertainty relative to the poses it was seen from (the gate's term).
        self.information = np.zeros((0, 2, 2))
        # Duplicates merged (merge.py) for one robot whose map no other node shares, in covariance form.
        assoc = config.association
        self.merger = (DuplicateMerger(assoc.merge_probability, assoc.merge_radius)
                       if assoc.merge_probability > 0 and config.em.map_form == "covariance" and single else None)
        self.merges = 0
        self.block_index = 1
        self.block_end = config.em.block_initial_length
        self.failed_solves = 0
        # Sharing with other nodes (segment_message.py): None, or the messages of this node's
        # segments not yet taken; the sequence numbers sent and received per robot.
        self.outbox: list[SegmentMessage] | None = None
        self._sent: dict[int, int] = {}
        self._received: dict[int, int] = {}

    def add_landmarks(self, count: int) -> None:
        self.system.add_landmarks(count)
        self.information = np.concatenate([self.information, np.zeros((count, 2, 2))])

    def keep_landmarks(self, keep: np.ndarray) -> None:
        self.system.keep_landmarks(keep)
        self.information = self.information[keep]

    def update(self, data: FilterStepData, table: LandmarkTable, robot: int = 0) -> np.ndarray | None:
        """Add the step's factors; at a segment end integrate its poses out and maybe solve.

        Returns ``robot``'s pose correction; the other robots' key poses keep their
        linearisation points (their corrections stay in the system until their own solve)."""
        self.system.add_step(self._step_factors(data, table), robot)
        if self.merger is not None and data.rows.size > 1:
            unnamed = data.rows[table.prunable[data.rows]]       # only landmarks made without an id merge
            if unnamed.size > 1:
                self.merger.seen_together(table.ids[unnamed])
        if not self._segment_ends(data.step, robot):
            return None
        segment = self.system.close_segment(table.theta, robot)
        self._send(segment, table, robot)
        if not self._solve_now(data.step):
            return None
        pose_correction = self._solve_and_move(table, robot)
        if pose_correction is not None and self.merger is not None and segment is not None and self.outbox is None:
            pose_correction = pose_correction + self._merge_duplicates(table, robot, segment.seen)
        return pose_correction

    def _solve_and_move(self, table: LandmarkTable, robot: int) -> np.ndarray | None:
        """The M-step: solve, the map into the table, ``robot``'s key moved to its solution;
        that key's correction (3,), None if the solve failed (counted)."""
        solution = self.system.solve()
        if solution is None:
            self.failed_solves += 1
            return None
        theta, keys = solution
        _take_solution(table, theta)
        correction = keys[POSE_DIM * robot:POSE_DIM * (robot + 1)].copy()
        self.system.move_key(correction, robot)
        return correction

    def _merge_duplicates(self, table: LandmarkTable, robot: int, recent: np.ndarray) -> np.ndarray:
        """Duplicates among the ``recent`` rows (the landmarks the segment saw) merged (merge.py),
        each by conditioning the map's Gaussian, then deleted as a pruned landmark is; the key
        pose's correction that follows."""
        correction = np.zeros(POSE_DIM)
        for _ in range(MAX_MERGES):
            pair = self.merger.best_pair(table, self.system, recent)
            if pair is None:
                break
            i, j = pair
            self.system.condition_equal(i, j)
            self.merger.merged(int(table.ids[i]), int(table.ids[j]))
            self.information[i] += self.information[j]
            table.n_obs[i] += table.n_obs[j]
            keep = np.arange(len(table)) != j
            table.keep(keep)
            self.keep_landmarks(keep)
            recent = recent[recent != j] - (recent[recent != j] > j)
            self.merges += 1
            shift = self._solve_and_move(table, robot)
            if shift is None:
                break
            correction += shift
        return correction

    def _step_factors(self, data: FilterStepData, table: LandmarkTable) -> StepFactors:
        """Motion and observation factors at the weighted mean pose xbar_t.

        The observation precision is R^-1 weighted by the particles' mixture
        responsibilities, averaged under the filtering weights; with heavy-tailed
        noise a landmark's first observation enters the map's system with
        FIRST_OBSERVATION_WEIGHT (the gate's per-landmark information keeps it in full).
        """
        pose = data.pose_mean()
        precision = np.einsum("n,npij->pij", data.weights, data.precision)
        if data.rows.size:
            H = landmark_jacobian(sensor_poses(pose, self.config.sensor)[None], table.theta[data.rows])
            np.add.at(self.information, data.rows, np.swapaxes(H, -1, -2) @ precision @ H)
            if self.config.noise.model != "gaussian":
                first = table.n_obs[data.rows] == 1                  # counted already: this is the first
                precision = np.where(first[:, None, None], FIRST_OBSERVATION_WEIGHT * precision, precision)
        return StepFactors(pose, data.motion_jacobian, motion_residual(data.motion_mean, pose), data.motion_cov,
                           data.rows.copy(), data.y.copy(), precision)

    def _segment_ends(self, step: int, robot: int) -> bool:
        if self.config.em.algorithm != "online" and step + 1 >= self.block_end:
            return True
        return len(self.system.segments[robot]) >= self.config.em.segment_length

    def _solve_now(self, step: int) -> bool:
        """Online EM solves at every segment end; Block Online EM only at block ends."""
        em = self.config.em
        if em.algorithm == "online":
            return True
        if step + 1 < self.block_end:
            return False
        self.block_index += 1
        self.block_end = step + 1 + int(np.ceil(em.block_initial_length * self.block_index ** em.block_growth))
        return True

    def restart_pose(self, pose: np.ndarray, pose_std, table: LandmarkTable, weights: np.ndarray | None = None,
                     robot: int = 0) -> None:
        """The filter (of ``robot``) was re-initialised at ``pose``: fold its open segment in,
        then restart its key pose without a motion link (the store's ``restart_key``).
        The replaced particles' ``weights`` do not matter: the segment holds the mean pose."""
        self._send(self.system.close_segment(table.theta, robot), table, robot)
        self.system.restart_key(pose, pose_std, robot)
        if self.outbox is not None:
            self._sent[robot] = self._sent.get(robot, 0) + 1
            self.outbox.append(SegmentMessage(robot, self._sent[robot], None, np.zeros(0, dtype=np.int64),
                                              np.zeros((0, 2)), np.array(pose, dtype=float),
                                              np.array(pose_std, dtype=float)))

    # ------------------------------------------------------------ other nodes
    def _send(self, segment, table: LandmarkTable, robot: int) -> None:
        if self.outbox is None or segment is None:
            return
        self._sent[robot] = self._sent.get(robot, 0) + 1
        self.outbox.append(SegmentMessage(robot, self._sent[robot], segment, table.ids[segment.seen].copy(),
                                          table.theta[segment.seen].copy()))

    def fold_remote(self, message: SegmentMessage, rows: np.ndarray, table: LandmarkTable) -> None:
        """Another node's segment of ``message.robot`` (``rows`` (S,): its landmarks' rows here):
        folded against that robot's key block, the map solved (its own robots' corrections stay
        in the system until their own segment ends, as in a fleet).

        A lost message (a gap in the robot's sequence) loses the motion between the keys on
        either side of it: the robot's key block restarts with the relocalisation prior at the
        next segment's key point, so the system stays a product of true factors (consistent),
        and only the link across the gap, and the gap's observations, are missing."""
        robot = message.robot
        if message.sequence != self._received.get(robot, 0) + 1 and message.segment is not None:
            self.system.restart_key(message.segment.key, self.config.filter.relocalisation_std, robot)
        self._received[robot] = message.sequence
        if message.segment is None:
            self.system.restart_key(message.pose, message.pose_std, robot)
            return
        self.system.fold(replace(message.segment, seen=rows), robot)
        solution = self.system.solve()
        if solution is None:
            self.failed_solves += 1
            return
        _take_solution(table, solution[0])

    # ------------------------------------------------------------ uncertainty
    def covariances(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        inverse, det = inv_det_2x2(self.information[rows])
        return np.where((det > 1e-300)[:, None, None], inverse, 0.0)

    def covariances_given_pose(self, rows: np.ndarray, robot: int = 0) -> np.ndarray:
        """(P, 2, 2) the landmarks' covariances given the robot's key pose, the map's frame since
        the robot last saw them included; NaN for those not in the stored Gaussian yet."""
        return self.system.covariances_given_key(rows, robot)

    def map_covariances(self) -> np.ndarray:
        """Marginals of the joint system (they include the frame's uncertainty); the
        per-landmark term for landmarks that have not reached it yet."""
        joint = self.system.landmark_covariances()
        if joint is None:
            return self.covariances()
        pending = np.isnan(joint[:, 0, 0])
        if pending.any():                         # a store may hand out its cached array
            joint = joint.copy()
            joint[pending] = self.covariances(pending)
        return joint

    # ------------------------------------------------------------ persistence
    def saved_arrays(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """The map's marginal information packed as complete-data statistics (A, A theta)."""
        m = self.information.shape[0]
        cov = self.map_covariances()
        info, det = inv_det_2x2(cov)
        info = np.where((det > 1e-300)[:, None, None], info, self.information)
        stats = np.zeros((m, STAT_DIM))
        stats[:, 0], stats[:, 1], stats[:, 2] = info[:, 0, 0], info[:, 0, 1], info[:, 1, 1]
        stats[:, 3:] = np.einsum("mij,mj->mi", info, theta)
        return {"count": np.ones(m, dtype=np.int64), "inv_n": np.ones(m), "stats": stats,
                "spread": np.zeros((m, 2, 2)), "avg_stats": np.zeros((m, STAT_DIM)),
                "avg_count": np.zeros(m, dtype=np.int64)}

    def restore(self, arrays: dict[str, np.ndarray], theta: np.ndarray) -> None:
        """A loaded map enters as a prior N(theta, A^-1) per landmark."""
        A, _ = unpack(arrays["stats"] / np.maximum(arrays["inv_n"], 1e-300)[:, None])
        m = theta.shape[0]
        self.add_landmarks(m)
        self.information[:] = A
        self.system.add_prior(np.arange(self.system.n_landmarks - m, self.system.n_landmarks), theta, A)


def _take_solution(table: LandmarkTable, theta: np.ndarray) -> None:
    """The solve's map into the table; a landmark the solve does not hold yet (NaN: its factors
    are still in a segment, covariance form) keeps its estimate."""
    table.theta[:] = np.where(np.isnan(theta), table.theta, theta)
