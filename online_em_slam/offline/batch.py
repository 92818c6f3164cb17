"""Batch maximum-likelihood reference on recorded inputs (a bag's event stream), known ids.

The problem of :mod:`.gtsam_batch` (prior, between factors, bearing-range
factors, Levenberg-Marquardt) built from the inputs an estimator is fed, in the
estimator's own bookkeeping, so the optimum is the reference for that run:

* one pose variable at the first input (the prior, ``initial_pose``) and one per
  observation scan the estimator filters (the runner's Feeder skips empty clouds
  and scans before the first motion input; the estimator refuses out-of-order stamps);
* between two pose variables, the motion the estimator compounds into its
  transition (T): the held control integrated up to each input (zero-order hold,
  each step clipped at ``motion.max_step``) or the odometry increments, each over
  the time since the previous input, Sigma <- F Sigma F^T + G Q G^T from the
  origin (the body frame of the earlier pose), plus ``step_jitter`` once per
  filter step.  A filter step without observations (``max_prediction_interval``
  exceeded) is marginalised: its jitter joins the running covariance;
* a bearing-range factor per observation with a known id (>= 0) that the
  estimator keeps (finite, range within [sensor.min_range, sensor.max_range],
  valid per-point stds, at most ``association.max_observations_per_scan``), R from
  :func:`noise_covariance` under :func:`information_noise` (the estimator's
  likelihood; equal to ``config.noise`` without serial correlation; with a correlation that
  decays with the viewpoint, each observation's own, :func:`viewpoint_changes`) with the
  per-point stds when given, on the scans the estimator uses: with
  ``filter.minimum_travel_*`` one once the motion since the last used scan reaches
  them, as the Feeder decides (a scan left out gets no pose variable);
* the observation's negative log-likelihood is the estimator's noise law
  (:func:`observation_noise_model`): a Student-t's exactly, through a robust kernel,
  so the optimum is the maximum a posteriori of the model online EM filters with;
  a mixture is taken as its Gaussian core R.  A sensor lever arm (offset_x, offset_y) uses a custom
  factor; without one, GTSAM's BearingRangeFactor2D with offset_yaw folded into
  the bearings, as :func:`.gtsam_batch.batch_estimate`.

The Pose2 tangent-space covariance is :func:`.gtsam_batch.tangent_covariance`;
the initial guess is dead reckoning and each landmark at its first observation,
or (``init="incremental"``, what offline/batch_run.py uses) the estimate of
iSAM2 run over the scans in order: on a real run of minutes the dead reckoning
drifts metres and Levenberg-Marquardt from it can stop in a local minimum.
gtsam is imported when the optimisation runs.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..core.config import SlamConfig
from ..core.filter.input_contract import MotionInput
from ..core.models.angles import wrap_angle
from ..core.models.motion import propagate, step_jitter
from ..core.models.observation import (information_noise, inverse_observation, noise_covariance,
                                       observation_correlation, sensor_poses, serial_decays, serially_weighed,
                                       viewpoint_change)
from ..pipeline.inputs import CONTROL, OBSERVATIONS, ODOMETRY
from ..pipeline.travel import MinimumTravel
from ..baselines.gtsam_batch import compose, levenberg_marquardt, symbols, tangent_covariance
from .extra_poses import ExtraPoses
from .observation_factors import lever_arm_factor, observation_noise_model


@dataclass
class InputsBatchResult:
    """The batch optimum on a run's inputs: T pose variables (the start, then one per scan)
    and M landmarks (known ids)."""

    stamps: np.ndarray                 # (T,) stamps[0] the first input's, then the scans'
    poses: np.ndarray                  # (T, 3)
    landmark_ids: np.ndarray           # (M,) ascending
    landmarks: np.ndarray              # (M, 2)
    initial_poses: np.ndarray          # (T, 3) the starting point (dead reckoning or incremental)
    initial_landmarks: np.ndarray      # (M, 2) its landmarks
    increments: np.ndarray             # (T-1, 3) body-frame motion between consecutive poses
    motion_covariances: np.ndarray     # (T-1, 3, 3) its covariance in that body frame (jitter included)
    n_observations: int                # bearing-range factors
    skipped: dict = field(default_factory=dict)   # inputs / observations left out, by reason
    initial_error: float = float("nan")
    final_error: float = float("nan")
    iterations: int = 0
    solve_time: float = 0.0            # s spent in gtsam (graph building and optimisation)


@dataclass
class InputsProblem:
    """What :func:`collect_problem` reads off the inputs (pure numpy): the factors' data."""

    stamps: np.ndarray
    increments: np.ndarray
    motion_covariances: np.ndarray
    obs_pose: np.ndarray               # (P,) pose variable of each observation
    obs_id: np.ndarray                 # (P,) landmark id
    obs_y: np.ndarray                  # (P, 2) range, bearing (sensor frame)
    obs_R: np.ndarray                  # (P, 2, 2) in (range, bearing) order
    skipped: Counter
    #: Pose variables that start a chain (a robot's first pose: a prior, no motion into it); a fleet's
    #: problems put end to end (offline/fleet_batch.py) have one per robot.
    chain_starts: tuple = (0,)


class _MotionBook:
    """The estimator's motion bookkeeping (OnlineEMSlam add_control / add_odometry /
    _advance_to / _predict) in the body frame of the last pose variable."""

    def __init__(self, config: SlamConfig, motion_source: str, skipped: Counter) -> None:
        self.motion = config.motion
        self.skipped = skipped
        self.input = MotionInput(config.motion, skipped)
        self.motion_kind = ODOMETRY if motion_source == "odom" else CONTROL
        self.motion_seen = False
        self.anchor: float | None = None
        self.start: float | None = None          # stamp of the first input used (the start pose)
        self.pose, self.cov = np.zeros(3), np.zeros((3, 3))
        # The Feeder's rule on the motion since the last used scan (``since_used``, in the
        # body frame of that scan's pose; None before the first): travel is the motion's alone.
        self.travel = MinimumTravel.from_config(config)
        self.since_used: np.ndarray | None = None

    def _predict(self, control: np.ndarray, dt: float) -> None:
        if dt > self.motion.max_step:
            self.skipped["large_time_step_clipped"] += 1
            dt = self.motion.max_step
        mean, F, Q = propagate(self.motion, self.pose[None], control, dt)
        self.pose, self.cov = mean[0], F[0] @ self.cov @ F[0].T + Q[0]

    def _advance_to(self, stamp: float) -> None:
        held = self.input
        if held.last_stamp is None:
            held.last_stamp = self.anchor = stamp
            self.start = stamp if self.start is None else self.start
            return
        for control, dt in held.held_segments(stamp):       # none for the odometry model: nothing held
            self._predict(control, dt)
        if stamp - self.anchor > self.motion.max_prediction_interval:
            self.cov = self.cov + step_jitter(self.motion)     # a filter step without observations
            self.anchor = stamp
            self.skipped["steps_without_observations"] += 1

    def motion_input(self, kind: int, stamp: float, payload) -> None:
        if kind != self.motion_kind:
            return                                  # the Feeder uses one motion source
        if kind == CONTROL:
            u = self.input.control(stamp, payload)
            if u is None:
                return
            self._advance_to(stamp)
            self.input.hold(stamp, u)
        else:
            usable, increment, dt = self.input.odometry_motion(stamp, payload)
            if not usable:
                return
            if increment is not None:
                self._predict(increment, max(dt, 0.0))
            self._advance_to(stamp)
        self.motion_seen = True

    def cut(self, stamp: float) -> tuple[np.ndarray, np.ndarray]:
        """The motion since the last pose variable up to ``stamp`` (>= the last input's), a pose
        variable the estimator does not have (:func:`collect_problem`'s ``extra_poses``).  The
        odometry model's next increment keeps its own time step, so only a held control is
        integrated; the step jitter keeps the covariance regular on a robot standing still."""
        if not self.motion.uses_odometry and stamp >= self.input.last_stamp:
            self._advance_to(stamp)
        out = (self.pose.copy(), self.cov + step_jitter(self.motion))
        if self.since_used is not None:
            self.since_used = compose(self.since_used, self.pose)
        self.pose, self.cov = np.zeros(3), np.zeros((3, 3))
        return out

    def scan(self, stamp: float, observations) -> tuple[np.ndarray, np.ndarray] | None:
        """The motion since the last pose variable (increment, covariance) if the estimator
        would filter this scan, else None (counted)."""
        if not len(observations):
            self.skipped["empty_cloud"] += 1
            return None
        if not self.motion_seen:
            self.skipped["no_motion_input"] += 1
            return None
        if not self.input.accept_stamp(stamp):
            return None
        self._advance_to(stamp)
        if not self._travelled():
            self.skipped["minimum_travel"] += 1
            return None
        out = (self.pose.copy(), self.cov + step_jitter(self.motion))
        self.pose, self.cov = np.zeros(3), np.zeros((3, 3))
        self.anchor = stamp
        return out

    def _travelled(self) -> bool:
        """The scan is due under ``filter.minimum_travel_*`` (the first always is); a due scan
        restarts the travel."""
        if not self.travel.enabled:
            return True
        if self.since_used is not None:
            self.travel.used(np.zeros(3))
            if not self.travel.due(compose(self.since_used, self.pose)):
                return False
        self.since_used = np.zeros(3)
        return True


def usable_observations(config: SlamConfig, obs, skipped: Counter) -> np.ndarray:
    """Mask of the observations the estimator keeps (OnlineEMSlam._valid_observations)."""
    sensor = config.sensor
    valid = np.isfinite(obs.ranges) & np.isfinite(obs.bearings) & (obs.ranges >= 0)
    std_ok = obs.valid_std()
    keep = valid & std_ok & (obs.ranges >= max(sensor.min_range, 0.0)) & (obs.ranges <= sensor.max_range)
    for reason, mask in (("invalid_observation", ~valid), ("invalid_std", valid & ~std_ok),
                         ("observation_out_of_range", valid & std_ok & ~keep)):
        skipped[reason] += int(mask.sum())
    beyond = np.flatnonzero(keep)[config.association.max_observations_per_scan:]
    keep[beyond] = False
    skipped["too_many_observations"] += int(beyond.size)
    return keep


def collect_problem(events, config: SlamConfig, motion_source: str | None = None,
                    extra_poses=()) -> InputsProblem:
    """Pose variables, compounded motion and observations from (kind, stamp, payload[, log_time]) events.

    ``extra_poses``: stamps (E,) that get a pose variable too, with no observation (a scan at the
    same stamp is that variable); those before the first motion input or after the last input
    get none (counted in ``skipped``).  Find them in the problem's ``stamps``.
    """
    config = config.validate()
    if motion_source is None:
        motion_source = "odom" if config.motion.uses_odometry else "control"
    skipped: Counter = Counter()
    book = _MotionBook(config, motion_source, skipped)
    decays = serial_decays(config.noise)
    noise = config.noise if decays else information_noise(config.noise)
    stamps, increments, covs = [], [], []
    obs_pose, obs_id, obs_y, obs_R = [], [], [], []
    extra = ExtraPoses(extra_poses, book, stamps, increments, covs)
    for event in events:
        kind, stamp, payload = event[0], float(event[1]), event[2]
        extra.before(stamp)
        if kind != OBSERVATIONS:
            book.motion_input(kind, stamp, payload)
            continue
        motion = book.scan(stamp, payload)
        if motion is None:
            continue
        extra.pose_variable(stamp, motion)
        keep = usable_observations(config, payload, skipped)
        known = keep & (payload.ids >= 0)
        skipped["unknown_id"] += int((keep & (payload.ids < 0)).sum())
        if not known.any():
            continue
        obs = payload.subset(known)
        obs_pose.append(np.full(len(obs), len(stamps) - 1))
        obs_id.append(obs.ids)
        obs_y.append(np.stack([obs.ranges, obs.bearings], axis=1))
        obs_R.append(noise_covariance(noise, obs.ranges, obs.range_std, obs.bearing_std))
    extra.finish()
    if not stamps and book.start is not None:
        stamps.append(book.start)
    cat = (lambda parts, shape, dtype=float: np.concatenate(parts).astype(dtype) if parts
           else np.zeros(shape, dtype=dtype))
    problem = InputsProblem(np.asarray(stamps, float), np.asarray(increments, float).reshape(-1, 3),
                            np.asarray(covs, float).reshape(-1, 3, 3), cat(obs_pose, (0,), np.int64),
                            cat(obs_id, (0,), np.int64), cat(obs_y, (0, 2)), cat(obs_R, (0, 2, 2)),
                            Counter({k: v for k, v in skipped.items() if v}))
    if decays:
        c = observation_correlation(config.noise, viewpoint_changes(problem, config))
        problem.obs_R = serially_weighed(problem.obs_R, c)
    return problem


def viewpoint_changes(problem: InputsProblem, config: SlamConfig) -> np.ndarray:
    """(P,) the viewpoint change of each observation since its landmark's previous one in the same
    chain (inf for a first sighting), as the estimator's serial weighing measures it
    (models/observation.py, viewpoint_change), between dead-reckoned sensor poses: their
    differences within a chain do not depend on where it starts."""
    poses = [np.zeros(3)]
    for k, increment in enumerate(problem.increments, start=1):
        poses.append(np.zeros(3) if k in problem.chain_starts else compose(poses[-1], increment))
    sensor = sensor_poses(np.array(poses)[problem.obs_pose], config.sensor)
    chain = np.searchsorted(np.asarray(problem.chain_starts), problem.obs_pose, side="right")
    order = np.lexsort((np.arange(problem.obs_id.size), problem.obs_id))     # by landmark, then in time
    same = (problem.obs_id[order][1:] == problem.obs_id[order][:-1]) & (chain[order][1:] == chain[order][:-1])
    previous = np.full(sensor.shape, np.nan)
    previous[order[1:][same]] = sensor[order[:-1][same]]
    return viewpoint_change(previous, sensor, config.noise.serial_turn_length)


def chain_starts(problem: InputsProblem, initial_pose) -> dict[int, np.ndarray]:
    """{pose variable: its chain's initial pose}: ``initial_pose`` (3,) or one (C, 3) row per chain."""
    starts = np.asarray(initial_pose, dtype=float).reshape(-1, 3)
    if len(starts) != len(problem.chain_starts):
        raise ValueError(f"{len(problem.chain_starts)} chains need as many initial poses, got {len(starts)}")
    return {int(k): pose for k, pose in zip(problem.chain_starts, starts)}


def initial_guess(problem: InputsProblem, config: SlamConfig, initial_pose) -> tuple:
    """Dead reckoning (T, 3) from each chain's initial pose; landmark ids (M,) ascending and each at its
    first observation (M, 2)."""
    starts = chain_starts(problem, initial_pose)
    poses = [starts[0]]
    for k, increment in enumerate(problem.increments, start=1):
        poses.append(starts[k] if k in starts else compose(poses[-1], increment))
    poses = np.array(poses)
    ids, first = np.unique(problem.obs_id, return_index=True)
    sensor = sensor_poses(poses[problem.obs_pose[first]], config.sensor)
    return poses, ids, inverse_observation(sensor, problem.obs_y[first]).reshape(-1, 2)


def batch_from_inputs(events, config: SlamConfig, initial_pose, max_iterations: int = 100,
                      initial_pose_std: tuple[float, float, float] = (1e-3, 1e-3, 1e-4),
                      motion_source: str | None = None, init: str = "dead_reckoning") -> InputsBatchResult:
    """The batch ML optimum on ``events`` (kind, stamp, payload[, log_time]) in the order the
    estimator is fed them (stamp-ordered, as the input path releases them).

    ``motion_source`` ("odom" or "control", the node setting; default from the motion
    model) says which motion input drives, as in the Feeder; the other kind is ignored.
    ``init``: the starting point of Levenberg-Marquardt, ``dead_reckoning`` (with each
    landmark at its first observation, as batch_estimate) or ``incremental``
    (:func:`incremental_guess`, for long real runs whose dead reckoning drifts far).
    """
    if init not in ("dead_reckoning", "incremental"):
        raise ValueError(f"init must be dead_reckoning or incremental, got {init!r}")
    problem = collect_problem(events, config, motion_source)
    if not problem.stamps.size:
        raise ValueError("batch_from_inputs: no motion input in the events")
    return solve_problem(problem, config, initial_pose, max_iterations, initial_pose_std, init)


def solve_problem(problem: InputsProblem, config: SlamConfig, initial_pose, max_iterations: int = 100,
                  initial_pose_std: tuple[float, float, float] = (1e-3, 1e-3, 1e-4),
                  init: str = "dead_reckoning", extra_factors=None) -> InputsBatchResult:
    """The batch ML optimum of a collected problem (:func:`batch_from_inputs`); ``initial_pose``: one
    (x, y, yaw) per chain of ``problem.chain_starts``.  ``extra_factors(gtsam)``: more factors on
    the pose variables (``symbols(gtsam)[0](k)``) for Levenberg-Marquardt, not for the starting point."""
    started = time.perf_counter()
    import gtsam  # optional dependency, see gtsam_batch

    if init == "incremental":
        initial, ids, landmark_guess = incremental_guess(gtsam, problem, config, initial_pose, initial_pose_std)
    else:
        initial, ids, landmark_guess = initial_guess(problem, config, initial_pose)

    X, L = symbols(gtsam)
    graph, values = build_graph(gtsam, problem, config, initial, ids, landmark_guess, initial_pose_std)
    for factor in extra_factors(gtsam) if extra_factors is not None else ():
        graph.add(factor)
    optimizer, result = levenberg_marquardt(gtsam, graph, values, max_iterations)
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(X(k)) for k in range(len(initial)))])
    landmarks = np.array([np.asarray(result.atPoint2(L(int(j))), float).reshape(2) for j in ids]).reshape(-1, 2)
    return InputsBatchResult(
        stamps=problem.stamps, poses=poses, landmark_ids=ids, landmarks=landmarks, initial_poses=initial,
        initial_landmarks=landmark_guess, increments=problem.increments,
        motion_covariances=problem.motion_covariances, n_observations=int(problem.obs_id.size),
        skipped=dict(problem.skipped), initial_error=float(graph.error(values)),
        final_error=float(graph.error(result)), iterations=int(optimizer.iterations()),
        solve_time=time.perf_counter() - started)


def build_graph(gtsam, problem: InputsProblem, config: SlamConfig, poses: np.ndarray, ids: np.ndarray,
                landmarks: np.ndarray, initial_pose_std=(1e-3, 1e-3, 1e-4)) -> tuple:
    """The factor graph (prior at poses[0], between and bearing-range factors) and the values
    ``poses`` (T, 3), landmarks ``ids`` (M,) at ``landmarks`` (M, 2)."""
    X, L = symbols(gtsam)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in problem.chain_starts:
        graph.add(_prior(gtsam, poses[k], initial_pose_std, k))
    for k, pose in enumerate(poses):
        values.insert(X(k), gtsam.Pose2(*pose))
    for j, guess in zip(ids, landmarks):
        values.insert(L(int(j)), gtsam.Point2(float(guess[0]), float(guess[1])))
    # Factor order as batch_estimate's (each step's motion, then its scan): the same graph, the same optimum.
    by_pose = np.searchsorted(problem.obs_pose, np.arange(len(poses) + 1))
    for k in range(1, len(poses)):
        _add_step(gtsam, graph, problem, config, k, by_pose)
    return graph, values


def _prior(gtsam, pose, initial_pose_std, k: int = 0):
    return gtsam.PriorFactorPose2(symbols(gtsam)[0](int(k)), gtsam.Pose2(*pose),
                                  gtsam.noiseModel.Diagonal.Sigmas(np.asarray(initial_pose_std, float)))


def incremental_guess(gtsam, problem: InputsProblem, config: SlamConfig, initial_pose,
                      initial_pose_std=(1e-3, 1e-3, 1e-4)) -> tuple:
    """(poses (T, 3), ids (M,), landmarks (M, 2)): iSAM2 over the scans in order, each pose
    predicted from the previous one's current estimate and each new landmark placed at
    its first observation from there.  A long run's dead reckoning can be metres off,
    and Levenberg-Marquardt from it may stop in a local minimum; this follows the optimum."""
    X, L = symbols(gtsam)
    starts = chain_starts(problem, initial_pose)
    isam = gtsam.ISAM2()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(_prior(gtsam, starts[0], initial_pose_std))
    values.insert(X(0), gtsam.Pose2(*starts[0]))
    isam.update(graph, values)
    by_pose = np.searchsorted(problem.obs_pose, np.arange(len(problem.stamps) + 1))
    previous, placed = starts[0], set()
    for k in range(1, len(problem.stamps)):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pose = starts[k] if k in starts else compose(previous, problem.increments[k - 1])
        if k in starts:
            graph.add(_prior(gtsam, pose, initial_pose_std, k))
        values.insert(X(k), gtsam.Pose2(*pose))
        sensor = sensor_poses(pose, config.sensor)
        for j, y in zip(problem.obs_id[by_pose[k]:by_pose[k + 1]], problem.obs_y[by_pose[k]:by_pose[k + 1]]):
            if int(j) not in placed:
                placed.add(int(j))
                values.insert(L(int(j)), gtsam.Point2(*inverse_observation(sensor, y)))
        _add_step(gtsam, graph, problem, config, k, by_pose)
        isam.update(graph, values)
        estimate = isam.calculateEstimatePose2(X(k))
        previous = np.array([estimate.x(), estimate.y(), estimate.theta()])
    estimate = isam.calculateEstimate()
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (estimate.atPose2(X(k)) for k in range(len(problem.stamps)))])
    ids = np.array(sorted(placed), dtype=np.int64)
    landmarks = np.array([np.asarray(estimate.atPoint2(L(int(j))), float).reshape(2) for j in ids]).reshape(-1, 2)
    return poses, ids, landmarks


def _add_step(gtsam, graph, problem: InputsProblem, config: SlamConfig, k: int, by_pose: np.ndarray) -> None:
    """The between factor into pose k (none into a chain's start) and the bearing-range factors of scan k."""
    X, L = symbols(gtsam)
    if k not in problem.chain_starts:
        increment = problem.increments[k - 1]
        cov = tangent_covariance(increment, problem.motion_covariances[k - 1])
        graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(*increment),
                                           gtsam.noiseModel.Gaussian.Covariance(cov)))
    rows = slice(by_pose[k], by_pose[k + 1])
    sensor = config.sensor
    offset = (sensor.offset_x, sensor.offset_y, sensor.offset_yaw)
    lever = sensor.offset_x != 0.0 or sensor.offset_y != 0.0
    for j, y, R in zip(problem.obs_id[rows], problem.obs_y[rows], problem.obs_R[rows]):
        if lever:
            graph.add(lever_arm_factor(gtsam, observation_noise_model(gtsam, R, config.noise), X(k), L(int(j)),
                                        y, offset))
            continue
        # GTSAM orders the BearingRange measurement as (bearing, range).
        cov = np.array([[R[1, 1], R[0, 1]], [R[1, 0], R[0, 0]]])
        bearing = gtsam.Rot2(float(wrap_angle(y[1] + sensor.offset_yaw)))
        graph.add(gtsam.BearingRangeFactor2D(X(k), L(int(j)), bearing, float(y[0]),
                                             observation_noise_model(gtsam, cov, config.noise)))


def released_events(inputs):
    """A runner BagInputs' events through the input path as the runner feeds them
    (online_em_slam.offline.runner.feed): (kind, stamp, payload), stamp-ordered; the path's
    refusals are added to ``inputs.refused``."""
    from ..pipeline import InputPath, merged_streams

    path = InputPath(merged_streams(inputs.motion_source), silence=inputs.input_delay,
                     jump_threshold=inputs.jump_threshold, restart_on_jump_back=False)
    refused: Counter = Counter()
    for kind, stamp, payload, log_time in inputs.events.stream(refused):
        for item in path.push(kind, stamp, payload, log_time).released:
            yield item.kind, item.stamp, item.payload
    for item in path.flush():
        yield item.kind, item.stamp, item.payload
    inputs.refused = refused + Counter({k: v for k, v in path.drops.items() if v})
