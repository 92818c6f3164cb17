"""Particle online EM SLAM: the public estimator (docs/METHOD.md).

The pose is the hidden state of an HMM and is tracked by a particle filter; the landmark map
theta is a parameter, updated by an M-step piece (em/complete.py: the seed's complete-data
M-step; em/observed.py: the Newton step with the observed information).  One *filter step*
happens per observation scan (and, without observations, every ``motion.max_prediction_interval``
seconds); the controls or odometry increments in between are compounded into the Gaussian
transition (T) of ``models/motion.py``, so the O(N^2) smoother runs once per scan, not once per
40 Hz control message.
"""
from __future__ import annotations

import time
from collections import Counter
from functools import cache

import numpy as np

from ..models import motion as motion_models
from ..models.angles import wrap_angle
from .association import Gates, candidate_rows, creations, plan_associations, predicted_measurements
from ..config import SlamConfig
from ..em.m_steps import make_m_step
from ..em.step import FilterStepData, MStep
from .input_contract import MotionInput, usable_observations
from ..mapping import mapfile, persistence
from ..mapping.landmarks import LandmarkTable
from ..em.noise.learner import NoiseLearner
from ..models.observation import sensor_poses
from .serial_errors import SerialWeighing
from .observation_terms import ObservationTerms, observation_terms, scan_noise
from .prediction import PendingMotion
from .warmup import WarmupReplay
from .particles import effective_sample_size, localised, normalize_log_weights, sample_gaussians, systematic_resample
from ..weighted import weighted_pose_covariance, weighted_pose_mean
from ..types import LandmarkMap, Observations, PoseEstimate, StepReport


class OnlineEMSlam:
    """Particle online EM / Block Online EM landmark SLAM.

    Feed motion with :meth:`add_control` (bicycle, acfr, unicycle models) or
    :meth:`add_odometry` (odometry model), observation scans with
    :meth:`add_observations`; read :meth:`pose`, :meth:`particles` and
    :meth:`landmarks`.  Inputs that cannot be used are dropped and counted in
    :attr:`drops` by reason; no input raises or produces NaN.
    """

    #: Lists that only grow, which a rollback (pipeline/rollback.py) shares instead of copying.
    append_only_lists = ("_warmup_log",)

    @property
    def _warmup_log(self) -> list | None:
        """The warm-up's inputs kept for the replay (None: none kept), owned by warmup.py."""
        return self._warmup.inputs

    def __init__(self, config: SlamConfig | None = None, initial_pose=(0.0, 0.0, 0.0),
                 stamp: float | None = None, m_step_factory=None) -> None:
        """``m_step_factory(config, initial_pose, rng) -> MStep`` replaces the piece
        chosen by ``em.m_step`` (baselines plug their map update in here)."""
        self.config = (config or SlamConfig()).validate()
        self._m_step_factory = m_step_factory or make_m_step
        self.drops: Counter[str] = Counter()
        self.replay_in_slices = False       # a live node's choice: see advance_replay
        self.reset(initial_pose, stamp)

    # ------------------------------------------------------------------ state
    def reset(self, initial_pose=None, stamp: float | None = None) -> None:
        """Forget map, statistics and trajectory; restart at ``initial_pose``."""
        cfg = self.config
        self._rng = np.random.default_rng(cfg.filter.seed)
        n = cfg.filter.num_particles
        pose = np.asarray(initial_pose if initial_pose is not None else self._initial_pose, dtype=float)
        self._initial_pose = pose.copy()
        # Views of each landmark when the serial correlation decays with them (serial_errors.py).
        self._serial = SerialWeighing(any(cfg.noise.serial_length) or (
            cfg.noise_learning.enabled and "serial_length" in cfg.noise_learning.learn))
        self._particles = np.tile(pose, (n, 1))
        std = np.asarray(cfg.filter.initial_pose_std, dtype=float)
        if np.any(std > 0):
            self._particles += self._rng.standard_normal((n, 3)) * std
            self._particles[:, 2] = wrap_angle(self._particles[:, 2])
        self._log_w = np.full(n, -np.log(n))
        self._pred_mean = self._particles.copy()
        self._pred_cov = np.zeros((n, 3, 3))
        self._resample_pending = False
        self._relocalising = False               # after a map load: no landmark created until localised
        self._input = MotionInput(cfg.motion, self.drops, stamp)
        self._anchor_time: float | None = stamp
        self._step = 0
        self._ess = float(n)
        self._map = LandmarkTable()
        self._m_step: MStep = self._m_step_factory(cfg, pose, self._rng)
        self._noise = NoiseLearner(cfg)          # learned noise (em/noise/learner.py); configured until warm
        # Queued segments and the mean pose's track (prediction.py).
        self._motion = PendingMotion(pose, len(self._noise.gains_learned))
        # The warm-up's inputs, filtered again once the learned noise is in use (warmup.py).
        replay = cfg.noise_learning.replay_warmup and bool(self._noise.learn)
        self._warmup = WarmupReplay(replay, cfg.noise_learning.max_replay_inputs, (pose.copy(), stamp),
                                    cfg.noise_learning.replay_on_calibration, cfg.noise_learning.replay_growth)

    def start_new_pass(self, initial_pose=None, stamp: float | None = None) -> None:
        """Another pass over the same data (batch EM by repeated passes; offline, how far EM is from
        its fixed point): the map theta, its ids and counts stay as the starting point, the statistics,
        step-size counts and filter restart, so the pass's M-steps replace the last pass's statistics."""
        # The complete-data statistics stay until each landmark's first update of the
        # new pass replaces them (step size 1): they give the map uncertainty meanwhile.
        saved = self._m_step_arrays()
        for name in ("count", "avg_stats", "avg_count"):
            saved[name] = np.zeros_like(saved[name])
        self.reset(initial_pose, stamp)
        persistence.restore_map(self._map, self._m_step, saved)
        self._warmup.discard()

    def set_pose(self, pose, std=None) -> None:
        """Put the robot at ``pose`` (an initial-pose message, a relocalisation after
        loading a map): the particles restart around it with ``std`` (default
        ``filter.initial_pose_std``); the map and its statistics stay."""
        pose = np.asarray(pose, dtype=float).reshape(-1)
        std = np.asarray(self.config.filter.initial_pose_std if std is None else std, dtype=float).reshape(-1)
        if pose.shape != (3,) or std.shape != (3,) or not (np.all(np.isfinite(pose)) and np.all(np.isfinite(std))):
            raise ValueError(f"set_pose needs a finite (x, y, yaw) and 3 finite stds, got {pose} and {std}")
        self._flush_motion()
        weights, _ = normalize_log_weights(self._log_w)
        restart = getattr(self._m_step, "restart_pose", None)      # a plugged-in map update may have none
        if restart is not None:
            restart(pose, std, self._map, weights)
        n = self._particles.shape[0]
        particles = pose + self._rng.standard_normal((n, 3)) * np.abs(std)
        particles[:, 2] = wrap_angle(particles[:, 2])
        self._particles, self._log_w = particles, np.full(n, -np.log(n))
        self._pred_mean, self._pred_cov = particles.copy(), np.zeros((n, 3, 3))
        self._motion.reset_track(pose)
        self._resample_pending, self._ess = False, float(n)
        self._anchor_time = self._input.last_stamp
        self._warmup.discard()           # the inputs so far no longer lead to this state

    def relocalise(self, pose, std=None) -> None:
        """The robot is near ``pose`` on the current map but may have moved (a map loaded
        after a restart): the particles spread with ``std`` (default
        ``filter.relocalisation_std``) and the known landmarks weigh them; no landmark is
        created (``relocalising``) until the cloud's position std is below
        ``filter.relocalisation_tolerance``, so a wrong guess does not duplicate the map."""
        self.set_pose(pose, self.config.filter.relocalisation_std if std is None else std)
        self._relocalising = len(self._map) > 0

    @property
    def relocalising(self) -> bool:
        return self._relocalising

    def advance_replay(self, max_inputs: int) -> bool:
        """With ``replay_in_slices`` (a live node, which cannot stop for the whole warm-up replay):
        feed the replay up to ``max_inputs`` kept inputs while this estimator goes on; it takes
        over once it has every input (filter/warmup.py).  True while it is still catching up."""
        return self._warmup.advance(self, max_inputs)

    def restart_time_line(self, pose, std=None) -> None:
        """A confirmed jump of the time line (a bag played in a loop, a clock set back):
        :meth:`set_pose` at ``pose`` and the next input starts a new time line (no held
        control, no odometry reference, no last stamp); the map and its statistics stay."""
        self.set_pose(pose, std)
        self._input.reset(None)
        self._anchor_time = None

    @property
    def last_stamp(self) -> float | None:
        return self._input.last_stamp

    @property
    def step_count(self) -> int:
        return self._step

    @property
    def effective_sample_size(self) -> float:
        return self._ess

    # ------------------------------------------------------------------ inputs
    def _predict(self, control: np.ndarray, dt: float) -> None:
        """Queue one motion segment; :meth:`_flush_motion` compounds the queue into (T)."""
        if dt > self.config.motion.max_step:
            self.drops["large_time_step_clipped"] += 1
            dt = self.config.motion.max_step
        self._motion.queue(control, dt)

    def _flush_motion(self) -> None:
        """Compound the queued control segments into the transition (T) in one pass (prediction.py)."""
        moved = self._motion.flush(self._noise.motion_config(), self._noise.gains_learned, self._pred_mean,
                                   self._pred_cov, self.drops, self._noise.motion_parts())
        if moved is not None:
            self._pred_mean, self._pred_cov = moved

    def _advance_to(self, stamp: float) -> None:
        """Integrate the held control up to ``stamp`` (zero-order hold)."""
        held = self._input
        if held.last_stamp is None:
            held.last_stamp = self._anchor_time = stamp
            return
        for control, dt in held.held_segments(stamp):       # none for the odometry model: nothing held
            self._predict(control, dt)
        if stamp - self._anchor_time > self.config.motion.max_prediction_interval:
            # Keep the Gaussian transition local: a filter step without observations.
            self._filter_step(None)

    def add_control(self, stamp: float, control) -> bool:
        """Control u = (speed, steering angle or yaw rate), held from ``stamp`` plus the drive's dead time
        in use (``motion.control_delay``, or the learned one) on."""
        self._warmup.record("add_control", stamp, control)
        u = self._input.control(stamp, control)
        if u is None:
            return False
        self._advance_to(float(stamp))
        self._input.hold(float(stamp), u, self._noise.motion_config().control_delay)   # the dead time in use
        return True

    def add_odometry(self, stamp: float, odom_pose) -> bool:
        """Odometry-frame pose (x, y, yaw); the increment since the previous one drives motion."""
        self._warmup.record("add_odometry", stamp, odom_pose)
        usable, increment, dt = self._input.odometry_motion(stamp, odom_pose)
        if not usable:
            return False
        if increment is not None:
            self._predict(increment, max(dt, 0.0))
        self._advance_to(float(stamp))
        return True

    def add_observations(self, stamp: float, observations: Observations) -> StepReport:
        """Run one filter step and EM update with a scan of range-bearing observations."""
        started = time.perf_counter()
        self._warmup.record("add_observations", stamp, observations)
        report = StepReport(n_observations=len(observations))
        if not self._input.accept_stamp(stamp):
            report.dropped["out_of_order"] = len(observations) or 1
            return report
        self._advance_to(float(stamp))
        observations = self._valid_observations(observations, report)
        self._filter_step(observations, report)
        if self._warmup.due(self._noise):
            self._warmup.replay(self, self.replay_in_slices)
        report.ess = self._ess
        report.duration = time.perf_counter() - started
        return report

    def _valid_observations(self, obs: Observations, report: StepReport) -> Observations:
        """The scan's usable observations (inputs.usable_observations); the others counted."""
        keep, dropped = usable_observations(obs, self.config.sensor, self.config.association.max_observations_per_scan)
        for reason, count in dropped.items():
            report.dropped[reason] = report.dropped.get(reason, 0) + count
            self.drops[reason] += count
        return obs.subset(keep) if not keep.all() else obs

    # ------------------------------------------------------------------ map rows
    def _add_landmarks(self, positions: np.ndarray, ids: np.ndarray, prunable) -> np.ndarray:
        """Append landmarks to the table and to the M-step's per-landmark state; their rows."""
        rows = self._map.add(positions, ids, self._step, prunable)
        self._m_step.add_landmarks(rows.size)
        return rows

    def _keep_landmarks(self, keep: np.ndarray) -> None:
        self._map.keep(keep)
        self._m_step.keep_landmarks(keep)

    # ------------------------------------------------------------------ filter step
    def _filter_step(self, obs: Observations | None, report: StepReport | None = None) -> None:
        """One particle-filter step and EM update (docs/METHOD.md, "Filter step")."""
        report = report if report is not None else StepReport()
        self._flush_motion()
        trans_cov = self._pred_cov * self._noise.motion_scale() + motion_models.step_jitter(self.config.motion)
        ancestors, log_prior, means, covs = self._select_ancestors(trans_cov)
        particles = sample_gaussians(means, covs, self._rng)
        sensor = sensor_poses(particles, self.config.sensor)
        prior_weights, _ = normalize_log_weights(log_prior)
        rows, obs_idx = self._associate_scan(obs, sensor, prior_weights, report)
        terms = self._observation_terms(obs, obs_idx, rows, sensor, ancestors, prior_weights)
        log_w = log_prior + terms.log_likelihood
        weights = self._normalise(log_w)
        data = self._step_data(particles, weights, prior_weights, ancestors, trans_cov, rows, terms, sensor)
        pose_correction = None
        if not self._relocalising:      # a cloud still looking for its pose teaches neither map nor noise
            self._noise.update(data, self._map.n_obs[rows], self._map.ids[rows])   # noise statistics (em/noise/)
            merges = getattr(self._m_step, "merges", 0)      # duplicates merged (em/merge.py): decisions
            pose_correction = self._m_step.update(data, self._map)
            if getattr(self._m_step, "merges", 0) > merges:
                self.drops["merged_duplicate_landmark"] += self._m_step.merges - merges
        self._commit(particles, weights, pose_correction, data)
        if self._relocalising and rows.size:
            self._relocalising = not localised(particles, weights, self.config.filter.relocalisation_tolerance)
        report.n_associated = int(rows.size)
        report.n_pruned = self._prune_tentative()

    def _select_ancestors(self, trans_cov: np.ndarray) -> tuple[np.ndarray, ...]:
        """Ancestor indices, prior log-weights and the ancestors' transitions (means, ``trans_cov``);
        resampling was decided on the last ESS."""
        n = self._particles.shape[0]
        if not self._resample_pending:
            return np.arange(n), self._log_w, self._pred_mean, trans_cov
        ancestors = systematic_resample(np.exp(self._log_w), self._rng)
        return ancestors, np.full(n, -np.log(n)), self._pred_mean[ancestors], trans_cov[ancestors]

    def _associate_scan(self, obs, sensor, prior_weights, report) -> tuple[np.ndarray, np.ndarray]:
        """(landmark rows, observation indices) of the scan's associated observations."""
        if obs is None or not len(obs):
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        obs_idx, rows = self._associate(obs, sensor, prior_weights, report)
        return rows, obs_idx

    def _observation_terms(self, obs, obs_idx, rows, sensor, ancestors, prior_weights) -> ObservationTerms:
        """Innovations, Jacobians, likelihood and responsibilities under theta_{t-1}; counts the observations.
        The likelihood weighs with the landmarks seen often enough (``inflate_with_map_uncertainty``: its
        covariance widened by H Sigma_k H^T; ``filter.serial_likelihood`` ar1: under AR(1) errors)."""
        if not rows.size:
            return ObservationTerms.empty(sensor.shape[0])
        cfg = self.config
        y = np.stack([obs.ranges[obs_idx], obs.bearings[obs_idx]], axis=-1)            # (P, 2)
        in_use = self._noise.noise_config()
        noise = self._noise.weighed_noise()      # serially correlated errors inform less
        ids = self._map.ids[rows]
        R, c = self._serial.scan_noise(in_use, noise, obs, obs_idx, ids, sensor, prior_weights)
        weighting = self._map.n_obs[rows] >= cfg.association.min_observations_for_weighting
        inflate = cfg.em.inflate_with_map_uncertainty and weighting.any()
        given = getattr(self._m_step, "covariances_given_pose", None)      # the observed M-step's
        widen = given and cfg.em.responsibilities_with_map_uncertainty and noise.model != "gaussian"
        terms = observation_terms(y, R, self._map.theta[rows], sensor, noise, weighting,
                                  self._m_step.covariances(rows) if inflate else None, given(rows) if widen else None)
        terms.serial = c
        if cfg.filter.serial_likelihood == "ar1":       # the weights under AR(1) errors (serial_errors.py)
            self._serial.last.weigh(terms, self._step, ids, scan_noise(in_use, obs, obs_idx), ancestors, in_use,
                                    weighting, c)
        self._map.n_obs[rows] += 1
        return terms

    def _normalise(self, log_w: np.ndarray) -> np.ndarray:
        weights, _ = normalize_log_weights(log_w)
        if not np.all(np.isfinite(log_w)):
            self.drops["degenerate_weights"] += 1
        return weights

    def _step_data(self, particles, weights, prior_weights, ancestors, trans_cov, rows, terms,
                   sensor) -> FilterStepData:
        return FilterStepData(
            step=self._step, particles=particles, weights=weights, log_weights_prev=self._log_w,
            prior_weights=prior_weights, ancestors=ancestors, transition_means=self._pred_mean,
            transition_covs=trans_cov, rows=rows, y=terms.y, R=terms.R, sensor=sensor, nu=terms.nu,
            H=terms.H, precision=terms.precision, serial=terms.serial, motion_mean=self._motion.pose,
            motion_jacobian=self._motion.jacobian,
            motion_cov=self._motion.cov * self._noise.motion_scale() + motion_models.step_jitter(self.config.motion),
            motion_gain_sensitivity=self._motion.sensitivity, motion_cov_parts=self._motion.cov_parts)

    def _commit(self, particles, weights, pose_correction, data: FilterStepData) -> None:
        """New anchors for the next transition, moved by the M-step's pose correction."""
        if pose_correction is not None:
            particles = particles + pose_correction
            particles[:, 2] = wrap_angle(particles[:, 2])
        self._particles = particles
        self._log_w = np.log(np.maximum(weights, 1e-300))
        self._pred_mean = particles.copy()
        self._pred_cov = np.zeros_like(self._pred_cov)
        mean = data.pose_mean() if pose_correction is None else weighted_pose_mean(particles, weights)
        self._motion.reset_track(mean)
        self._ess = effective_sample_size(weights)
        self._resample_pending = self._ess < self.config.filter.resample_threshold * particles.shape[0]
        self._anchor_time = self._input.last_stamp
        self._step += 1

    # ------------------------------------------------------------------ association
    def _associate(self, obs: Observations, sensor: np.ndarray, prior_weights: np.ndarray,
                   report: StepReport) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (observation index, landmark row); creates landmarks as needed."""
        w = prior_weights / prior_weights.sum()
        mean_sensor = cache(lambda: weighted_pose_mean(sensor, w))       # only unknown ids and creations need it
        y = np.stack([obs.ranges, obs.bearings], axis=-1)

        def candidates(unknown):
            noise = self._noise.noise_config()
            reach = self.config.sensor.max_range + 5.0 * noise.sigma_range + 5.0
            rows = candidate_rows(self._map.theta, mean_sensor(), reach)
            if not rows.size:
                return rows, np.zeros((0, 2)), np.zeros((unknown.size, 0, 2, 2))
            R = scan_noise(noise, obs, unknown)
            return (rows,) + predicted_measurements(self._map.theta[rows], sensor, w, self._m_step.covariances(rows),
                                                    self.config.association, R)

        def drop(reason, n):
            if n > 0:
                report.dropped[reason] = report.dropped.get(reason, 0) + n
                self.drops[reason] += n

        gates = Gates.from_config(self.config.association, self._noise.noise_config())   # learned dof moves them
        plan = plan_associations(obs.ids, y, self._map.rows_of_ids, candidates, gates, drop)
        new_rows = self._create_landmarks(plan, y, mean_sensor, drop)
        report.n_created = int(new_rows.size)
        return (np.concatenate([plan.update_obs, plan.create_obs[:new_rows.size]]),
                np.concatenate([plan.update_rows, new_rows]).astype(int))

    def _create_landmarks(self, plan, y: np.ndarray, mean_sensor, drop) -> np.ndarray:
        """Landmarks for the plan's creations (association.creations) at ``mean_sensor()``, none while
        relocalising; their rows.  The kept creations are the first entries of ``plan.create_obs`` afterwards."""
        if not plan.create_obs.size:
            return np.zeros(0, dtype=int)
        if self._relocalising:
            drop("relocalising", len(plan.create_obs))
            return np.zeros(0, dtype=int)
        radius = 2.0 * self._noise.noise_config().sigma_range
        positions, ids, prunable = creations(plan, y, mean_sensor(), self._map, self.config.association, radius,
                                             drop, self.drops)
        return self._add_landmarks(positions, np.array(ids), prunable) if ids else np.zeros(0, dtype=int)

    def _prune_tentative(self) -> int:
        assoc = self.config.association
        stale = self._map.stale(self._step, assoc.confirm_observations, assoc.tentative_timeout)
        if stale.any():
            self._keep_landmarks(~stale)
        return int(stale.sum())

    # ------------------------------------------------------------------ outputs
    def pose(self) -> PoseEstimate:
        """Weighted mean pose at the last input stamp, with its covariance."""
        self._flush_motion()
        w = np.exp(self._log_w - self._log_w.max())
        w /= w.sum()
        mean = weighted_pose_mean(self._pred_mean, w)
        cov = weighted_pose_covariance(self._pred_mean, w, mean, self._pred_cov)
        return PoseEstimate(self._input.last_stamp, mean, cov)

    def learned_noise(self) -> dict:
        """Noise values learned online (em/noise/learner.py): estimates, counts, and whether in use."""
        return {**self._noise.learned(), "warmup_replayed": self._warmup.replayed, "replays": self._warmup.replays,
                "calibration_replayed": self._warmup.calibrated, "warmup_replay_needless": self._warmup.needless}

    def revised_trajectory(self) -> np.ndarray | None:
        """(n, 4) stamp, x, y, yaw after each scan the last replay filtered (warmup.py); None: no replay."""
        return self._warmup.trajectories.get(0)

    def learned_noise_parameters(self) -> dict:
        """The noise in use as flat node parameters (noise.*, motion.* stds), for a parameter file."""
        return self._noise.parameters()

    def particles(self) -> tuple[np.ndarray, np.ndarray]:
        """Particle poses (predicted to the last input stamp) and normalised weights."""
        self._flush_motion()
        w = np.exp(self._log_w - self._log_w.max())
        return self._pred_mean.copy(), w / w.sum()

    def landmarks(self, confirmed_only: bool = False) -> LandmarkMap:
        """Current map estimate theta with covariances and observation counts."""
        table = self._map
        keep = table.confirmed if confirmed_only else np.ones(len(table), dtype=bool)
        cov = self._m_step.map_covariances()
        cov = np.where(np.isfinite(cov), cov, 0.0)
        return LandmarkMap(table.ids[keep].copy(), table.theta[keep].copy(), cov[keep],
                           table.n_obs[keep].copy(), table.confirmed[keep].copy())

    # ------------------------------------------------------------------ persistence
    def _m_step_arrays(self) -> dict[str, np.ndarray]:
        """What the map file holds: the landmark table and the M-step's per-landmark state."""
        return persistence.map_arrays(self._map, self._m_step)

    def resume_from_file(self, loaded: dict[str, np.ndarray], relocalise_at=None) -> None:
        """After a map file's map is in (:meth:`load_map`, FleetSlam.load_map): its learned noise starts
        the learner (when learning is on and the mixture's size matches), the warm-up is forgotten and
        the robot relocalises around ``relocalise_at`` (3,) (None: it stays where it was reset)."""
        try:
            saved = persistence.saved_noise(loaded, self.config.noise)
        except ValueError:
            saved = None
            self.drops["map_noise_mismatch"] += 1      # another noise model: keep the configured one
        if saved is not None:
            self._noise.start_from(*saved)             # the file has no motion gains: they are learned again
        self._warmup.discard()
        if relocalise_at is not None:
            self.relocalise(relocalise_at)

    def save_map(self, path: str) -> None:
        """Write map, statistics, counts and pose atomically (core/mapping/mapfile.py), validated first
        (a non-finite estimate never replaces a good file); the directory must exist."""
        data = self._m_step_arrays()
        data["pose"] = self.pose().mean
        data.update(self._noise.saved_values() or {})
        mapfile.write_map(path, data)

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        """Load a map written by :meth:`save_map`; EM continues from its statistics and counts.

        The file is validated completely before the state is touched; on any error
        (MapFileError, a ValueError naming the file) the estimate is left unchanged.
        """
        loaded = mapfile.read_map(path, max_landmarks=self.config.association.max_landmarks)
        pose = persistence.saved_pose(loaded) if restore_pose else None
        # reset() rebinds attributes rather than mutating arrays, so a shallow copy of
        # the instance dict is a complete snapshot to fall back to.
        snapshot = dict(self.__dict__)
        try:
            self.reset(pose, self._input.last_stamp)
            persistence.restore_map(self._map, self._m_step, loaded)
            self.resume_from_file(loaded, pose)
        except BaseException:
            self.__dict__.clear()
            self.__dict__.update(snapshot)
            raise
