"""Seeded simulator of the seed experiment (GRETSI 2011, figure 1).

In the style of Tim Bailey's classic SLAM simulator: a vehicle with the seed
bicycle model drives around a closed route of waypoints (steering controller
with bounded steering angle and rate), landmarks stand on both sides of the
route, and a range-bearing sensor observes every landmark within ``max_range``
in front of the vehicle at every step.

Generative model (docs/METHOD.md, "Model"):

    X_k = f(X_{k-1}, u_k)                             true controls, no noise  (S1)
    u~_k = u_k + V_k,  V_k ~ N(0, diag(sigma_v^2, sigma_psi^2))  controls given to the filter (S2)
    Y_{k,j} = h(X_k, theta_j) + W_{k,j},  W ~ N(0, R)  (or N(0, s R) w.p. p_outlier)  (S3)

Step k (1..T) carries the control u~_k applied over [t_{k-1}, t_k] and the scan
taken at t_k = k dt from the true pose X_k.  The landmark layout and the route
are deterministic; ``seed`` draws only the noises, so Monte Carlo replications
share one map, as in the seed's 100-run experiment.

Long runs (``ScenarioConfig.laps = L``): the route is a closed loop of
waypoints, but the seed run starts on waypoint 0 while later laps pass it at
the waypoint radius, so its first lap differs from the others and its 1500
steps end mid-lap.  With laps the vehicle starts on the controller's periodic
path (510 steps per lap with the defaults) and drives exactly L laps: every lap
is the same closed path, with fresh noise (one random stream per lap).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.config import (AssociationConfig, FilterConfig, MotionConfig, ObservationNoiseConfig, SensorConfig,
                           SlamConfig)
from ..core.models.observation import noise_covariance, predict_observation
from ..core.types import Observations

# Closed route (m), a rounded irregular loop of about 330 m: at 3 m/s and
# 1500 steps of 0.2 s (900 m) the vehicle drives it about 2.7 times.
DEFAULT_WAYPOINTS = (
    (0.0, 0.0), (40.0, -10.0), (80.0, 0.0), (100.0, 30.0),
    (80.0, 60.0), (40.0, 55.0), (0.0, 60.0), (-20.0, 30.0),
)


@dataclass
class ScenarioConfig:
    """Settings of one simulated run (SI units; defaults = seed experiment)."""

    n_landmarks: int = 20
    n_steps: int = 1500
    dt: float = 0.2
    speed: float = 3.0
    wheelbase: float = 4.0
    max_steering: float = math.radians(30.0)
    max_steering_rate: float = math.radians(20.0)
    waypoint_radius: float = 3.0
    waypoints: tuple[tuple[float, float], ...] = DEFAULT_WAYPOINTS
    landmark_offset: tuple[float, float] = (7.0, 14.0)
    max_range: float = 30.0
    sigma_speed: float = 0.5
    sigma_steering: float = math.pi / 60
    sigma_range: float = 0.5
    sigma_bearing: float = math.pi / 60
    rho: float = 0.01
    outlier_probability: float = 0.0
    outlier_scale: float = 25.0
    # Student-t observation noise t_dof(0, R) instead of N(0, R) when set (heavy tails)
    noise_dof: float | None = None
    # sigma_r(range) = sigma_range + range_growth * range (the thesis' context-dependent noise)
    range_growth: float = 0.0
    # Each landmark's observation error W_t = c W_{t-1} + sqrt(1 - c^2) e_t from step to step
    # (AR(1): a detector that repeats its error), the same marginal N(0, R)
    serial_correlation: float = 0.0
    known_ids: bool = True
    seed: int = 0
    # laps > 0: drive the closed route exactly ``laps`` times (n_steps is then
    # derived, see drive_route); 0 keeps the seed run of n_steps steps.
    laps: int = 0


@dataclass
class SimStep:
    """One step: control u~_k held over [control_stamp, stamp], then the scan at ``stamp``."""

    stamp: float
    control_stamp: float
    control: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    ids: np.ndarray
    true_ids: np.ndarray
    outlier: np.ndarray

    def observations(self) -> Observations:
        """The scan as the estimators' :class:`Observations`."""
        return Observations(self.ranges.copy(), self.bearings.copy(), self.ids.copy())


@dataclass
class Scenario:
    """A simulated run: ground truth and the inputs given to the estimators."""

    config: ScenarioConfig
    true_poses: np.ndarray          # (T+1, 3), true_poses[0] = initial pose at t = 0
    landmarks: np.ndarray           # (M, 2)
    true_controls: np.ndarray       # (T, 2)
    controls: np.ndarray            # (T, 2) noisy controls given to the filter
    stamps: np.ndarray              # (T+1,) t_k = k dt
    steps: list[SimStep] = field(default_factory=list)
    # (L,) number of steps driven when each lap of the route is completed
    lap_ends: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def initial_pose(self) -> np.ndarray:
        return self.true_poses[0].copy()

    @property
    def n_steps(self) -> int:
        return len(self.steps)


def bicycle_step(pose: np.ndarray, control: np.ndarray, dt: float, wheelbase: float) -> np.ndarray:
    """Noise-free seed bicycle model (S1):
    X' = X + (v dt cos(phi + psi), v dt sin(phi + psi), v dt sin(psi) / B)."""
    v, psi = control
    heading = pose[2] + psi
    return np.array([pose[0] + v * dt * math.cos(heading),
                     pose[1] + v * dt * math.sin(heading),
                     wrap_angle(pose[2] + v * dt * math.sin(psi) / wheelbase)])


def steer_towards(pose: np.ndarray, target: np.ndarray, steering: float, cfg: ScenarioConfig) -> float:
    """Steering command toward ``target``: the heading error, rate- then angle-limited.

    The rate limit smooths the corners (Bailey's simulator uses the same two limits).
    """
    error = wrap_angle(math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2])
    max_change = cfg.max_steering_rate * cfg.dt
    wanted = min(max(error, steering - max_change), steering + max_change)
    return float(min(max(wanted, -cfg.max_steering), cfg.max_steering))


def route_polyline(waypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed polyline: segment start points, unit directions, and cumulative arc lengths."""
    ends = np.roll(waypoints, -1, axis=0)
    seg = ends - waypoints
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    return seg / lengths[:, None], np.concatenate([[0.0], np.cumsum(lengths)])


def landmark_layout(cfg: ScenarioConfig) -> np.ndarray:
    """M landmarks evenly spaced in arc length along the route, alternating sides.

    Offsets alternate between the two ``landmark_offset`` distances so that
    landmarks are not collinear; with offsets well under ``max_range`` every
    landmark is in front of the vehicle within range for several seconds per lap.
    """
    waypoints = np.asarray(cfg.waypoints, dtype=float)
    directions, cumulative = route_polyline(waypoints)
    s = (np.arange(cfg.n_landmarks) + 0.5) * cumulative[-1] / cfg.n_landmarks
    seg = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(waypoints) - 1)
    along = s - cumulative[seg]
    points = waypoints[seg] + along[:, None] * directions[seg]
    normals = np.stack([-directions[seg, 1], directions[seg, 0]], axis=1)
    index = np.arange(cfg.n_landmarks)
    side = np.where(index % 2 == 0, 1.0, -1.0)
    near, far = cfg.landmark_offset
    offset = np.where((index // 2) % 2 == 0, near, far)
    return points + (side * offset)[:, None] * normals


def _drive(cfg: ScenarioConfig, pose: np.ndarray, steering: float, n_steps: int, laps: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steer around the cyclic waypoints from ``pose`` (heading for waypoint 1) for
    ``n_steps`` steps, or until the ``laps``-th lap when laps > 0.

    A lap ends at the step where the vehicle reaches waypoint 0 again (the
    controller then turns to waypoint 1).  Returns poses (T+1, 3), controls
    (T, 2) and lap ends (L,) in steps.  The loop is over time because the
    controller needs the current pose; it is scalar arithmetic (a few ms).
    """
    waypoints = np.asarray(cfg.waypoints, dtype=float)
    poses, controls, lap_ends = [pose], [], []
    target = 1
    while len(controls) < n_steps or laps > 0:
        if math.hypot(*(waypoints[target] - pose[:2])) < cfg.waypoint_radius:
            target = (target + 1) % len(waypoints)
            if target == 1:
                lap_ends.append(len(controls))
                if len(lap_ends) == laps:
                    break
        steering = steer_towards(pose, waypoints[target], steering, cfg)
        controls.append((cfg.speed, steering))
        pose = bicycle_step(pose, np.asarray(controls[-1]), cfg.dt, cfg.wheelbase)
        poses.append(pose)
    return (np.array(poses), np.array(controls, dtype=float).reshape(-1, 2),
            np.array(lap_ends, dtype=np.int64))


def route_start(cfg: ScenarioConfig) -> np.ndarray:
    """Start of the seed run: on waypoint 0, heading for waypoint 1."""
    w = np.asarray(cfg.waypoints, dtype=float)
    return np.array([w[0, 0], w[0, 1], math.atan2(w[1, 1] - w[0, 1], w[1, 0] - w[0, 0])])


def periodic_start(cfg: ScenarioConfig, tolerance: float = 1e-9, max_laps: int = 50
                   ) -> tuple[np.ndarray, float]:
    """(pose, steering) at the lap boundary of the controller's periodic path.

    From the seed start the first lap differs from the later ones (by up to
    2.3 m: the vehicle starts on waypoint 0 instead of passing it at the
    waypoint radius); the lap-boundary state then converges to a fixed point
    within a few laps (510 steps per lap with the defaults).  Starting there
    makes every lap the same closed path.
    """
    pose, steering = route_start(cfg), 0.0
    for _ in range(max_laps):
        poses, controls, _ = _drive(cfg, pose, steering, 0, laps=1)
        if np.max(np.abs(poses[-1] - pose)) < tolerance and abs(controls[-1, 1] - steering) < tolerance:
            break
        pose, steering = poses[-1], float(controls[-1, 1])
    return pose, steering


def drive_route(cfg: ScenarioConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True poses (T+1, 3), true controls (T, 2) and lap ends (L,) (S1).

    ``laps == 0``: the seed run, ``n_steps`` steps from waypoint 0 (about 2.7
    laps).  ``laps > 0``: the route's periodic path (:func:`periodic_start`)
    driven exactly ``laps`` times, so T = laps x the lap length and the run
    ends where it started.
    """
    if cfg.laps > 0:
        pose, steering = periodic_start(cfg)
        return _drive(cfg, pose, steering, 0, cfg.laps)
    return _drive(cfg, route_start(cfg), 0.0, cfg.n_steps, 0)


def noise_config(cfg: ScenarioConfig) -> ObservationNoiseConfig:
    """Observation noise section matching (S3); mixture weights (1-p, p) when outliers are on,
    Student-t with ``noise_dof``."""
    if cfg.noise_dof is not None:
        return ObservationNoiseConfig(model="student_t", dof=cfg.noise_dof, sigma_range=cfg.sigma_range,
                                      sigma_bearing=cfg.sigma_bearing, rho=cfg.rho, range_growth=cfg.range_growth)
    if cfg.outlier_probability > 0:
        return ObservationNoiseConfig(model="mixture", sigma_range=cfg.sigma_range,
                                      sigma_bearing=cfg.sigma_bearing, rho=cfg.rho,
                                      mixture_weights=(1.0 - cfg.outlier_probability, cfg.outlier_probability),
                                      mixture_scales=(1.0, cfg.outlier_scale), range_growth=cfg.range_growth)
    return ObservationNoiseConfig(sigma_range=cfg.sigma_range, sigma_bearing=cfg.sigma_bearing, rho=cfg.rho,
                                  range_growth=cfg.range_growth)


def draw_noise(rng: np.random.Generator, cfg: ScenarioConfig, n_steps: int, n_landmarks: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Control noise V (T, 2) (S2), observation noise W (T, M, 2) and outlier flags
    (T, M) (S3) for every (step, landmark) pair, drawn in this order from ``rng``."""
    V = rng.standard_normal((n_steps, 2)) * np.array([cfg.sigma_speed, cfg.sigma_steering])
    R = noise_covariance(ObservationNoiseConfig(sigma_range=cfg.sigma_range,
                                                sigma_bearing=cfg.sigma_bearing, rho=cfg.rho),
                         np.zeros(()))
    W = rng.standard_normal((n_steps, n_landmarks, 2)) @ np.linalg.cholesky(R).T   # W ~ N(0, R)
    if cfg.serial_correlation > 0:
        c = cfg.serial_correlation
        for t in range(1, n_steps):
            W[t] = c * W[t - 1] + math.sqrt(1.0 - c * c) * W[t]
    outlier = rng.random((n_steps, n_landmarks)) < cfg.outlier_probability
    W = np.where(outlier[..., None], math.sqrt(cfg.outlier_scale) * W, W)          # N(0, s R)
    if cfg.noise_dof is not None:                       # t_dof(0, R): N(0, R / tau), tau ~ Gamma(dof/2, dof/2)
        tau = rng.gamma(0.5 * cfg.noise_dof, 2.0 / cfg.noise_dof, (n_steps, n_landmarks))
        W = W / np.sqrt(tau)[..., None]
    return V, W, outlier


def run_noise(cfg: ScenarioConfig, n_steps: int, n_landmarks: int, lap_ends: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`draw_noise` for the whole run.  With laps, each lap draws from its
    own stream (SeedSequence(seed).spawn): fresh noise every lap, and an L-lap
    run is the exact prefix of any longer one, so checkpoints after each lap of
    a long run equal separate shorter runs."""
    if cfg.laps <= 0:
        return draw_noise(np.random.default_rng(cfg.seed), cfg, n_steps, n_landmarks)
    bounds = np.concatenate([[0], lap_ends])
    streams = np.random.SeedSequence(cfg.seed).spawn(len(lap_ends))
    laps = [draw_noise(np.random.default_rng(stream), cfg, int(b - a), n_landmarks)
            for stream, a, b in zip(streams, bounds[:-1], bounds[1:])]
    return tuple(np.concatenate(parts) for parts in zip(*laps))


def simulate(cfg: ScenarioConfig | None = None, landmarks: np.ndarray | None = None) -> Scenario:
    """Simulate one run: true trajectory (S1), noisy controls (S2), scans (S3).

    With ``cfg.laps > 0`` the returned ``config.n_steps`` is the derived run length.
    ``landmarks`` (M, 2) replace the layout of ``cfg`` (:func:`fleet_scenarios`).
    """
    cfg = cfg or ScenarioConfig()
    landmarks = landmark_layout(cfg) if landmarks is None else np.asarray(landmarks, dtype=float)
    poses, true_controls, lap_ends = drive_route(cfg)
    if cfg.laps > 0:
        cfg = replace(cfg, n_steps=len(true_controls))
    V, W, outlier = run_noise(cfg, len(true_controls), len(landmarks), lap_ends)
    controls = true_controls + V

    # All (step, landmark) pairs at once: visible if within range and in front.
    clean = predict_observation(poses[1:, None, :], landmarks[None, :, :])        # (T, M, 2)
    visible = (clean[..., 0] <= cfg.max_range) & (np.abs(clean[..., 1]) <= math.pi / 2)
    if cfg.range_growth > 0:       # (S3) with sigma_r(r): the range noise (and its covariance) scaled
        W = W.copy()
        W[..., 0] *= 1.0 + cfg.range_growth * clean[..., 0] / cfg.sigma_range
    measured = clean + W
    measured[..., 0] = np.abs(measured[..., 0])   # a range is never negative (only matters < 2 m)
    measured[..., 1] = wrap_angle(measured[..., 1])

    stamps = np.arange(cfg.n_steps + 1) * cfg.dt
    steps = []
    for k in range(cfg.n_steps):
        seen = np.flatnonzero(visible[k])
        ids = seen if cfg.known_ids else np.full(seen.shape, -1, dtype=np.int64)
        steps.append(SimStep(stamp=float(stamps[k + 1]), control_stamp=float(stamps[k]),
                             control=controls[k].copy(),
                             ranges=measured[k, seen, 0], bearings=measured[k, seen, 1],
                             ids=ids.astype(np.int64), true_ids=seen.astype(np.int64),
                             outlier=outlier[k, seen]))
    return Scenario(config=cfg, true_poses=poses, landmarks=landmarks, true_controls=true_controls,
                    controls=controls, stamps=stamps, steps=steps, lap_ends=lap_ends)


def fleet_scenarios(cfg: ScenarioConfig, n_robots: int) -> list[Scenario]:
    """``n_robots`` runs among the one landmark layout of ``cfg`` (same ids for every robot):
    robot r drives the route from waypoint floor(r W / R) on (the waypoints rotated), its
    noise drawn with seed ``cfg.seed + r``.  The robots' true starts are their
    ``initial_pose`` in the common frame (the fleet's initial poses)."""
    landmarks = landmark_layout(cfg)
    scenarios = []
    for robot in range(n_robots):
        k = robot * len(cfg.waypoints) // n_robots
        waypoints = tuple(cfg.waypoints[k:]) + tuple(cfg.waypoints[:k])
        scenarios.append(simulate(replace(cfg, waypoints=waypoints, seed=cfg.seed + robot), landmarks))
    return scenarios


def slam_config_for(scenario: Scenario | ScenarioConfig, num_particles: int = 100,
                    seed: int | None = 0) -> SlamConfig:
    """Core configuration whose models match the simulator: bicycle (wheelbase B),
    per-step control noise = the simulated one (noise_reference_period = dt), R and range.

    The association gate gets a 2 m / 0.05 rad pose margin: the drift accumulated
    over a lap (several metres before the first loop closure) is otherwise
    outside the gate and revisited landmarks would be created twice."""
    cfg = scenario.config if isinstance(scenario, Scenario) else scenario
    motion = MotionConfig(model="bicycle", wheelbase=cfg.wheelbase, sigma_speed=cfg.sigma_speed,
                          sigma_steering=cfg.sigma_steering, noise_reference_period=cfg.dt)
    sensor = SensorConfig(max_range=cfg.max_range)
    filt = FilterConfig(num_particles=num_particles, seed=seed)
    association = AssociationConfig(gate_position_std=2.0, gate_heading_std=0.05)
    return SlamConfig(motion=motion, sensor=sensor, noise=noise_config(cfg), filter=filt,
                      association=association).validate()


def feed(estimator, step: SimStep):
    """Drive an estimator through one step with the zero-order-hold convention:
    hold u~_k from t_{k-1}, then process the scan at t_k.  Returns the step report."""
    estimator.add_control(step.control_stamp, step.control)
    return estimator.add_observations(step.stamp, step.observations())


def landmark_rmse(estimated_ids: np.ndarray, estimated: np.ndarray, truth: np.ndarray) -> float:
    """RMSE of estimated landmarks whose id indexes the true landmark array (known ids)."""
    ids = np.asarray(estimated_ids, dtype=int)
    keep = (ids >= 0) & (ids < len(truth))
    if not keep.any():
        return float("nan")
    err = np.asarray(estimated)[keep] - truth[ids[keep]]
    return float(np.sqrt(np.mean(np.sum(err * err, axis=1))))
