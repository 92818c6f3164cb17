"""Typed configuration of the estimation core.

Every field has an SI unit and a default that reproduces the seed experiment
(GRETSI 2011: N = 100 particles, sigma_v = 0.5 m/s, sigma_psi = pi/60 rad,
sigma_r = 0.5 m, sigma_b = pi/60 rad, rho = 0.01).  Each field is declared with
:func:`param`: its description and allowed range or choices live in the field's
metadata (:class:`ParamInfo`), the one source of the checks of ``validate``, of
the ROS parameter descriptors and of config/online_em_slam.yaml (parameters/specs.py,
:func:`core_parameters`).  ``validate`` raises ``ValueError`` naming the
offending field and its allowed range, so the ROS node and the command-line
tools can refuse bad values with one message; checks that are not a range
(list lengths, one field bounding another) are code in ``validate``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Iterator

from .config_fields import ParamInfo, check_fields, check_length, check_range, param, param_info
from .noise_learning_config import NoiseLearningConfig

# The motion models, by name, and the input each integrates: a held control (speed,
# steering angle) or (speed, yaw rate), or odometry pose increments.  models/motion.py
# holds each model's equations in the function of its name.
MOTION_INPUTS = {"bicycle": "steering", "acfr": "steering", "unicycle": "yaw_rate", "odometry": "odometry"}
MOTION_MODELS = tuple(MOTION_INPUTS)
NOISE_MODELS = ("gaussian", "mixture", "student_t")
SMOOTHERS = ("forward", "paris", "ancestry")
SERIAL_LIKELIHOODS = ("inflated", "ar1")
EM_ALGORITHMS = ("online", "block", "block_averaged")
M_STEPS = ("complete", "observed")
MAP_FORMS = ("information", "covariance")


MIN_JITTER = 1e-9            # smallest motion jitter std (m, rad); see MotionConfig.position_jitter
INT32_MAX = 2 ** 31 - 1
_STD = (0.0, 100.0)          # range of a motion noise std


@dataclass
class MotionConfig:
    """Vehicle motion model and its noise.

    model:
      ``bicycle``  seed model, control (speed v, steering psi), wheelbase B;
      ``acfr``     ACFR ute: rear-left encoder speed, steering alpha, wheelbase L,
                   encoder offset H (KTH datasets);
      ``unicycle`` control (speed v, yaw rate omega);
      ``odometry`` pose increments read off an odometry source.
    Control noise standard deviations are given for ``noise_reference_period``
    seconds and scaled as continuous-time white noise for other step lengths,
    so the filter behaves the same at 40 Hz or at 5 Hz control input.
    max_speed (m/s) and max_yaw_rate (rad/s) bound what the vehicle can do: a
    control or odometry increment beyond them is physically impossible, dropped
    and counted, so one absurd but finite value cannot poison the estimate.
    """

    model: str = param("bicycle", choices=MOTION_MODELS,
                       doc="Motion model: bicycle, acfr, unicycle or odometry.")
    wheelbase: float = param(4.0, 0.0, 100.0, lo_open=True,
                             doc="Wheelbase B of the bicycle model / L of the acfr model (m).")
    encoder_offset: float = param(0.76, -10.0, 10.0, doc="acfr model: lateral offset H of the speed encoder (m).")
    translation_gain: float = param(1.0, 0.1, 10.0, doc="Calibration of the motion input: the speed (odometry: "
                                    "the translation increment) is multiplied by this.")
    rotation_gain: float = param(1.0, 0.1, 10.0, doc="Calibration of the motion input: the steering angle or "
                                 "yaw rate (odometry: the rotation increment) is multiplied by this.")
    rotation_in_place_gain: float = param(0.0, 0.0, 10.0, doc="Calibration of the motion input: the yaw rate "
                                          "(or steering angle) commanded at zero speed, a turn in place, is "
                                          "multiplied by this instead of rotation_gain (a differential drive's "
                                          "controllers can deliver a turn in place and one while driving in "
                                          "different shares; not the odometry model). 0: rotation_gain.")
    control_delay: float = param(0.0, 0.0, 5.0, doc="Dead time of the drive (s): a control (speed, steering "
                                 "or yaw rate command) moves the vehicle from this long after its stamp on "
                                 "(not the odometry model, which measures the motion itself).")
    turn_per_meter: float = param(0.0, -1.0, 1.0, doc="Calibration of the motion input, unicycle model: the "
                                  "yaw rate delivered beyond the commanded one per metre driven (rad/m), "
                                  "rotation_gain omega + turn_per_meter v: a differential drive whose wheels "
                                  "differ a little in diameter turns while commanded straight.")
    sigma_speed: float = param(0.5, *_STD, doc="Speed noise std (m/s) over noise_reference_period.")
    sigma_steering: float = param(math.pi / 60, *_STD, doc="Steering angle / yaw rate noise std (rad, rad/s) "
                                  "over noise_reference_period.")
    sigma_heading: float = param(0.0, *_STD, doc="Extra heading noise std (rad) over noise_reference_period.")
    sigma_speed_relative: float = param(0.0, 0.0, 10.0, doc="Speed noise std per unit of speed (a fraction of "
                                        "the speed) over noise_reference_period: a commanded speed is "
                                        "delivered less exactly the faster it is (not the odometry model).")
    sigma_steering_relative: float = param(0.0, 0.0, 10.0, doc="Steering angle / yaw rate noise std per unit of "
                                           "steering or yaw rate (a fraction of it) over "
                                           "noise_reference_period (not the odometry model).")
    noise_reference_period: float = param(0.2, 0.0, 100.0, lo_open=True, doc="Period (s) the control noise "
                                          "stds refer to; scaled as white noise for other control periods.")
    odometry_translation_std: float = param(0.01, *_STD,
                                            doc="Odometry model: translation noise std per step (m).")
    odometry_rotation_std: float = param(0.002, *_STD, doc="Odometry model: rotation noise std per step (rad).")
    odometry_translation_per_meter: float = param(0.05, *_STD, doc="Odometry model: translation noise std "
                                                  "per metre driven.")
    odometry_rotation_per_radian: float = param(0.05, *_STD, doc="Odometry model: rotation noise std per "
                                                "radian turned.")
    odometry_rotation_per_meter: float = param(0.01, *_STD, doc="Odometry model: rotation noise std (rad) "
                                               "per metre driven.")
    # The jitter keeps the step covariance positive definite: squared, a std of 1e-300
    # underflows to 0 and the Cholesky factorisation of the next step fails.
    position_jitter: float = param(1e-3, MIN_JITTER, 10.0, doc="Position jitter std (m) added per step "
                                   "(keeps particles diverse and the step covariance positive definite).")
    heading_jitter: float = param(1e-4, MIN_JITTER, 1.0, doc="Heading jitter std (rad) added per step.")
    max_step: float = param(1.0, 0.0, 3600.0, lo_open=True, doc="Longest motion step integrated at once (s); "
                            "longer gaps are clipped and counted (large_time_step_clipped).")
    max_prediction_interval: float = param(1.0, 0.0, 3600.0, lo_open=True, doc="A filter step without "
                                           "observations runs after this many seconds of motion only (s).")
    max_speed: float = param(50.0, 0.0, 1e4, lo_open=True, doc="Controls or odometry increments faster than "
                             "this (m/s) are physically impossible: dropped and counted.")
    max_yaw_rate: float = param(10.0, 0.0, 1e3, lo_open=True, doc="Yaw rates beyond this (rad/s) are "
                                "physically impossible: dropped and counted.")

    @property
    def motion_input(self) -> str:
        """What the model integrates (MOTION_INPUTS): "steering", "yaw_rate" or "odometry"."""
        return MOTION_INPUTS[self.model]

    @property
    def uses_odometry(self) -> bool:
        """The model integrates odometry increments, not held controls."""
        return self.motion_input == "odometry"

    def validate(self, prefix: str = "motion") -> None:
        check_fields(self, prefix)
        if self.turn_per_meter != 0.0 and self.model != "unicycle":
            raise ValueError(f"{prefix}.turn_per_meter is a calibration of the unicycle model's yaw rate, "
                             f"not of the {self.model} model's input")


@dataclass
class SensorConfig:
    """Range-bearing sensor mounted at (offset_x, offset_y, offset_yaw) in the base frame."""

    offset_x: float = param(0.0, -100.0, 100.0, doc="Sensor mount x in the base frame (m).")
    offset_y: float = param(0.0, -100.0, 100.0, doc="Sensor mount y in the base frame (m).")
    offset_yaw: float = param(0.0, -math.pi, math.pi, doc="Sensor mount yaw in the base frame (rad).")
    max_range: float = param(30.0, 0.0, 1e4, lo_open=True, doc="Observations farther than this are dropped (m).")
    min_range: float = param(0.0, 0.0, 1e4, doc="Observations nearer than this are dropped (m), "
                             "<= sensor.max_range.")

    def validate(self, prefix: str = "sensor") -> None:
        check_fields(self, prefix, {"min_range": {"hi": self.max_range}})


@dataclass
class ObservationNoiseConfig:
    """Range-bearing noise W: Gaussian N(0, R), the outlier-robust mixture or Student-t.

    R = [[sigma_r^2, rho], [rho, sigma_b^2]] (seed notation: rho is the covariance
    term).  Mixture: sum_c weight_c N(0, scale_c R) (seed: 0.8 N(0,R) + 0.2 N(0,5R)).
    Student-t: t_dof(0, R), a Gaussian whose precision is scaled by a Gamma(dof/2,
    dof/2) variable: a tight core with heavy tails, R the core's scale; its
    association gates are quantiles of the t (2 F(2, dof)), not of the chi-square.
    ``range_growth`` makes the range noise grow with range:
    sigma_r(range) = sigma_range + range_growth * range (thesis 003: context-dependent noise).
    """

    model: str = param("gaussian", choices=NOISE_MODELS, doc="Observation noise: gaussian N(0,R), mixture "
                       "sum_c w_c N(0, s_c R) (outlier-robust) or student_t t_dof(0, R) (heavy-tailed).")
    sigma_range: float = param(0.5, 0.0, 100.0, lo_open=True, doc="Range noise std sigma_r (m).")
    sigma_bearing: float = param(math.pi / 60, 0.0, math.pi, lo_open=True, doc="Bearing noise std sigma_b (rad).")
    rho: float = param(0.01, doc="Range-bearing covariance term of R (m rad); |rho| < 0.999 sigma_range "
                       "sigma_bearing.")
    # Each entry checked on its own: NaN compares False with everything, so a NaN weight
    # would pass the sum test of validate and give degenerate particle weights.
    mixture_weights: tuple[float, ...] = param((0.8, 0.2), 0.0, 1.0, doc="Mixture component weights, "
                                               "summing to 1.")
    mixture_scales: tuple[float, ...] = param((1.0, 5.0), 0.0, 1e6, lo_open=True, doc="Mixture component "
                                              "covariance scales, as many as weights.")
    range_growth: float = param(0.0, 0.0, 1.0, doc="Range std grows by this times the range: "
                                "sigma_r + growth * range.")
    dof: float = param(4.0, 0.5, 1e4, doc="Degrees of freedom of the student_t noise (small: heavy tails; "
                       "large: Gaussian).")
    serial_correlation: tuple[float, float] = param((0.0, 0.0), 0.0, 0.99, doc="Correlation of a landmark's "
                                                    "observation errors from one scan to the next (range, "
                                                    "bearing): each observation then informs as (1 - c) / (1 + c) "
                                                    "of an independent one (R x (1 + c) / (1 - c) in the "
                                                    "likelihood and the M-step).")
    # A camera's error repeats while its view of the landmark does (docs/METHOD.md, "Serially
    # correlated errors"): 0 keeps one correlation for every observation.
    serial_length: tuple[float, float] = param((0.0, 0.0), 0.0, 1e3, doc="Viewpoint change (m) over which "
                                               "the serial correlation decays by e (range, bearing): an "
                                               "observation's c = serial_correlation x exp(-v / length), v the "
                                               "sensor's travel plus serial_turn_length per radian turned since "
                                               "the landmark's previous sighting (a first sighting: c = 0); 0: one "
                                               "c for every observation.")
    serial_turn_length: float = param(1.2, 0.0, 1e3, doc="Viewpoint change (m) a turn of one radian counts "
                                      "as in the serial correlation's decay (noise.serial_length).")

    def validate(self, prefix: str = "noise") -> None:
        weights = check_length(f"{prefix}.mixture_weights", self.mixture_weights)
        scales = check_length(f"{prefix}.mixture_scales", self.mixture_scales)
        check_length(f"{prefix}.serial_correlation", self.serial_correlation, 2, " (range, bearing)")
        check_length(f"{prefix}.serial_length", self.serial_length, 2, " (range, bearing)")
        if len(weights) != len(scales):
            raise ValueError(f"{prefix}.mixture_weights and {prefix}.mixture_scales must have the same, non-zero length")
        check_fields(self, prefix)
        limit = 0.999 * self.sigma_range * self.sigma_bearing
        # Named with its bound's cause: lowering sigma_range or sigma_bearing alone can put the
        # default rho (0.01) outside it, and the user never set rho.
        check_range(f"{prefix}.rho", self.rho, -limit, limit,
                    bound=f"|rho| <= 0.999 {prefix}.sigma_range {prefix}.sigma_bearing "
                          f"({self.sigma_range:g} x {self.sigma_bearing:g}); set {prefix}.rho with them")
        if abs(math.fsum(float(w) for w in weights) - 1.0) > 1e-6:
            raise ValueError(f"{prefix}.mixture_weights = {self.mixture_weights} must be non-negative and sum to 1")


@dataclass
class FilterConfig:
    """Particle filter and the smoother that carries the E-step statistics."""

    num_particles: int = param(100, 1, 100000, doc="Number of particles N.")
    resample_threshold: float = param(0.5, 0.0, 1.0, doc="Resample when ESS < threshold * N.")
    smoother: str = param("forward", choices=SMOOTHERS,
                          doc="Sufficient-statistics smoother: forward, paris or ancestry.")
    paris_draws: int = param(2, 1, 100, doc="PaRIS backward draws per particle.")
    seed: int | None = param(0, 0, INT32_MAX, optional=True, doc="Random seed; None draws a fresh seed.")
    initial_pose_std: tuple[float, float, float] = param((0.0, 0.0, 0.0), 0.0, 1e3, doc="Std of the initial "
                                                         "particle cloud: exactly 3 values (x m, y m, yaw rad).")
    relocalisation_std: tuple[float, float, float] = param((2.0, 2.0, 0.5), 0.0, 1e3, doc="Std of the particle "
                                                           "cloud around the saved pose when a map is loaded (the "
                                                           "robot may have moved since): 3 values (x m, y m, yaw "
                                                           "rad). No landmark is created until the cloud has "
                                                           "narrowed to relocalisation_tolerance.")
    relocalisation_tolerance: float = param(0.5, 0.0, 1e3, lo_open=True, doc="Position std (m, largest axis) "
                                            "of the particle cloud below which a relocalisation is over.")
    minimum_travel_distance: float = param(0.0, 0.0, 1e3, doc="An observation update only once the robot has "
                                           "travelled this far (m) since the last one, or turned "
                                           "minimum_travel_heading; 0 with minimum_travel_heading 0: every scan. "
                                           "A robot standing still reads the same errors again.")
    minimum_travel_heading: float = param(0.0, 0.0, 2.0 * math.pi, doc="... or turned this much (rad) since "
                                          "the last observation update; see minimum_travel_distance.")
    serial_likelihood: str = param("inflated", choices=SERIAL_LIKELIHOODS, doc="The particles' likelihood "
                                   "of serially correlated errors (noise.serial_correlation c): inflated (each "
                                   "observation independent under R (1 + c) / (1 - c)) or ar1 (exact for AR(1) "
                                   "errors: a landmark seen at the step before by the particle's ancestor weighs "
                                   "by the quasi-difference nu_t - c nu_(t-1) under R - C R C). The M-step "
                                   "takes R (1 + c) / (1 - c) either way.")

    def validate(self, prefix: str = "filter") -> None:
        check_length(f"{prefix}.initial_pose_std", self.initial_pose_std, 3, " (x, y, yaw)")
        check_length(f"{prefix}.relocalisation_std", self.relocalisation_std, 3, " (x, y, yaw)")
        check_fields(self, prefix)


@dataclass
class EMConfig:
    """Online EM (stochastic approximation) or Block Online EM.

    online:          gamma_n = n^-step_size_exponent per landmark (n = its update count).
    block:           blocks of length ceil(block_initial_length * k^block_growth) steps (k = block index).
    block_averaged:  block statistics averaged over all past blocks, weighted by block length.

    m_step:
      ``complete``  the seed's M-step theta_k = A_k^-1 b_k on the smoothed
                    complete-data statistics (poses treated as known);
      ``observed``  a Newton step with the observed information: the joint
                    Gauss-Newton system over poses and map at the filter's mean
                    poses, poses integrated out every ``segment_length`` steps
                    (docs/METHOD.md, "Observed-information M-step").
    first_estimate_jacobians: the observed M-step takes each pose's and landmark's
                    Jacobians at its first estimate (FEJ) so that the linearised
                    system leaves the map's orientation unobserved, as the
                    nonlinear problem does.
    relinearize_threshold: a landmark farther than this (m) from the point its
                    Jacobians were taken at gets Jacobians at its current
                    estimate for its next factors.
    map_form:       how the observed M-step holds the map's Gaussian: ``information``
                    (observed_information.py) or ``covariance`` (observed_covariance.py).
    segment_iterations: Gauss-Newton iterations of a segment (its poses and landmarks
                    relinearised at the last solution) before its poses are integrated
                    out (1: linearised once, at the filter's mean poses).
    """

    algorithm: str = param("online", choices=EM_ALGORITHMS, doc="online (stochastic approximation), block or "
                           "block_averaged (Block Online EM).")
    step_size_exponent: float = param(0.8, 0.5, 1.0, lo_open=True,
                                      doc="Online EM step size gamma_n = n^-exponent.")
    min_updates_before_mstep: int = param(1, 1, 1000, doc="EM updates of a landmark before its M-step.")
    block_initial_length: int = param(20, 1, 100000, doc="Block Online EM: first block length (steps).")
    block_growth: float = param(1.1, 0.0, 3.0, doc="Block Online EM: block k has length initial * k^growth.")
    inflate_with_map_uncertainty: bool = param(False, doc="Add the landmark covariance to the innovation "
                                               "covariance.")
    responsibilities_with_map_uncertainty: bool = param(
        False, doc="Observed M-step, Student-t or mixture noise: the noise law's responsibilities (an "
        "observation's weight) from R + H Sigma H^T, Sigma the landmark's covariance given the robot's pose "
        "(the map's frame since the robot last saw it included), so that an observation closing a loop is "
        "not taken for an outlier; it also takes in outliers among a landmark's first sightings.")
    m_step: str = param("observed", choices=M_STEPS, doc="complete (seed: A^-1 b per landmark) or observed "
                        "(Newton step with the observed information: poses integrated out of the joint system).")
    segment_length: int = param(10, 1, 100000, doc="Observed M-step: filter steps per segment whose poses are "
                                "integrated out.")
    relinearize_threshold: float = param(0.5, 0.0, 1e3, lo_open=True, doc="Observed M-step: a landmark farther "
                                         "than this (m) from its first estimate gets new Jacobians for its "
                                         "next factors.")
    first_estimate_jacobians: bool = param(True, doc="Observed M-step: Jacobians at each variable's first "
                                           "estimate, so the map's orientation gains no false information (FEJ).")
    map_form: str = param("covariance", choices=MAP_FORMS, doc="Observed M-step: the map's Gaussian held as "
                          "information (a Cholesky solve per segment, O(M^3)) or covariance (mean and covariance "
                          "updated per segment, O(M^2)); the same estimate.")
    segment_iterations: int = param(1, 1, 20, doc="Observed M-step, covariance form, one robot: Gauss-Newton iterations of "
                                    "a segment, each relinearising its poses and landmarks at the last solution, "
                                    "before its poses are integrated out (a fixed lag of one segment); 1: linearised "
                                    "once.")

    def validate(self, prefix: str = "em") -> None:
        check_fields(self, prefix)
        if self.segment_iterations > 1 and self.map_form != "covariance":
            raise ValueError(f"{prefix}.segment_iterations > 1 needs {prefix}.map_form covariance")


@dataclass
class AssociationConfig:
    """Data association for observations with unknown id (-1).

    gate_probability:          chi-square(2) probability of the association gate.
    new_landmark_probability:  an observation outside this (wider) gate of every
                               landmark creates a landmark; between the two gates it
                               is ambiguous and dropped (counted).
    confirm_observations:      a tentative landmark becomes confirmed after this many
                               observations; unconfirmed ones made without an id older
                               than ``tentative_timeout`` observation steps are pruned
                               (a landmark whose id the sensor read is kept).
    min_observations_for_weighting: landmarks seen fewer times do not weight particles.
    gate_position_std / gate_heading_std: extra pose uncertainty (m, rad) added to
                               the innovation covariance of the association gate only.
                               The particle cloud measures the pose relative to the map;
                               drift accumulated before a loop closure is not in it, and
                               without this margin a revisited landmark is created twice.
    max_observations_per_scan: usable points of one scan beyond this are dropped
                               (``too_many_observations``): a bound on the memory and
                               time one message can cost.
    max_new_landmarks_per_scan: landmarks one scan may create (after merging); the
                               nearest creations are kept, the others dropped
                               (``new_landmark_limit``).  The M-step's joint system is
                               O(M^2) in memory, so this bounds what one hostile scan
                               adds, and with ``tentative_timeout`` what a sustained
                               flood keeps: at most this times (timeout + 1) tentative rows.
    merge_probability / merge_radius: duplicate landmarks merged at segment ends
                               (em/merge.py, docs/METHOD.md "Duplicate landmarks").
    """

    # Both gates are chi-square quantiles: a probability of 1 is an infinite gate.
    gate_probability: float = param(0.99, 0.0, 1.0, lo_open=True, hi_open=True,
                                    doc="Chi-square(2) probability of the association gate.")
    new_landmark_probability: float = param(0.9999, 0.0, 1.0, lo_open=True, hi_open=True, doc="Outside this "
                                            "wider gate of every landmark an unknown-id observation creates a "
                                            "landmark; >= gate_probability.")
    confirm_observations: int = param(3, 1, 1000, doc="Observations that confirm a tentative landmark.")
    tentative_timeout: int = param(20, 1, 1000000, doc="Unconfirmed landmarks made without an id older than "
                                   "this many steps are pruned.")
    min_observations_for_weighting: int = param(2, 1, 1000, doc="Landmarks seen fewer times do not weight "
                                                "particles.")
    max_landmarks: int = param(5000, 1, 1000000, doc="Map size limit; further new landmarks are dropped "
                               "(map_full).")
    gate_position_std: float = param(0.0, 0.0, 100.0, doc="Extra pose position std (m) in the association gate "
                                     "only: drift accumulated before a loop closure, so revisited landmarks "
                                     "are re-associated instead of duplicated.")
    gate_heading_std: float = param(0.0, 0.0, 3.2, doc="Extra heading std (rad) in the association gate only.")
    max_observations_per_scan: int = param(1000, 1, 100000, doc="Usable points of one scan beyond this are "
                                           "dropped (too_many_observations).")
    max_new_landmarks_per_scan: int = param(50, 1, 100000, doc="Landmarks one scan may create; the nearest "
                                            "are kept, the others dropped (new_landmark_limit). Bounds the "
                                            "growth of the O(M^2) map system by a flood of unknown points.")
    merge_probability: float = param(0.999, 0.0, 1.0, hi_open=True, doc="Two confirmed landmarks made "
                                     "without an id, never seen in one scan, are merged when their difference "
                                     "lies within this chi-square(2) gate of the map's joint Gaussian (a loop "
                                     "closure; observed M-step in covariance form, one robot); 0: never.")
    merge_radius: float = param(2.0, 0.0, 1000.0, lo_open=True, doc="Merge candidates are looked for this close "
                                "(m) to the landmarks a segment saw: a bound on the search, the gate decides.")

    def validate(self, prefix: str = "association") -> None:
        check_fields(self, prefix, {"new_landmark_probability": {"lo": self.gate_probability, "lo_open": False}})


@dataclass
class SlamConfig:
    """All settings of :class:`online_em_slam.core.filter.slam.OnlineEMSlam`."""

    motion: MotionConfig = field(default_factory=MotionConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    noise: ObservationNoiseConfig = field(default_factory=ObservationNoiseConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    em: EMConfig = field(default_factory=EMConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    noise_learning: NoiseLearningConfig = field(default_factory=NoiseLearningConfig)

    def validate(self) -> "SlamConfig":
        for f in fields(self):
            getattr(self, f.name).validate(f.name)
        if "motion_drift" in self.noise_learning.learn and self.motion.model != "unicycle":
            raise ValueError("noise_learning.learn: motion_drift (motion.turn_per_meter) is learned for the "
                             f"unicycle model, not the {self.motion.model} model")
        return self

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> "SlamConfig":
        """Build from a nested dict (YAML); unknown keys raise ValueError."""
        data = dict(data or {})
        kwargs = {}
        for f in fields(cls):
            section = data.pop(f.name, None) or {}
            sub_cls = f.default_factory  # type: ignore[misc]
            kwargs[f.name] = _section_from_dict(sub_cls, section, f.name)
        if data:
            raise ValueError(f"unknown configuration section(s): {', '.join(sorted(data))}")
        return cls(**kwargs).validate()


def core_parameters() -> Iterator[tuple[str, Any, ParamInfo]]:
    """(dotted name, default, ParamInfo) of every core setting, in field order:
    what parameters/specs.py turns into parameter specs and descriptors."""
    for section in fields(SlamConfig):
        for f in fields(section.default_factory):  # type: ignore[arg-type]
            yield f"{section.name}.{f.name}", f.default, param_info(f)


def _section_from_dict(sub_cls, section: dict[str, Any], name: str):
    known = {f.name: f for f in fields(sub_cls)}
    unknown = set(section) - set(known)
    if unknown:
        raise ValueError(f"unknown {name} setting(s): {', '.join(sorted(unknown))}")
    values = {}
    for key, value in section.items():
        default = getattr(sub_cls(), key)
        if isinstance(default, tuple):
            value = (value,) if isinstance(value, str) else tuple(value)    # "range" is one name, not 5
        elif isinstance(default, bool):
            value = bool(value)
        elif isinstance(default, float) and isinstance(value, int):
            value = float(value)
        values[key] = value
    return sub_cls(**values)


def replace_section(config: SlamConfig, **sections: Any) -> SlamConfig:
    """Copy ``config`` with whole sections replaced (helper for benchmarks and tests)."""
    data = {f.name: getattr(config, f.name) for f in fields(config)}
    data.update(sections)
    return SlamConfig(**data)

