"""Typed configuration of the estimation core.

Every field has an SI unit and a default that reproduces the seed experiment
(GRETSI 2011: N = 100 particles, sigma_v = 0.5 m/s, sigma_psi = pi/60 rad,
sigma_r = 0.5 m, sigma_b = pi/60 rad, rho = 0.01).  ``validate`` raises
``ValueError`` naming the offending field and its allowed range, so the ROS
node and the command-line tools can refuse bad values with one message.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

MOTION_MODELS = ("bicycle", "acfr", "unicycle", "odometry")
NOISE_MODELS = ("gaussian", "mixture")
SMOOTHERS = ("forward", "paris", "ancestry")
EM_ALGORITHMS = ("online", "block", "block_averaged")
M_STEPS = ("complete", "observed")


MIN_JITTER = 1e-9            # smallest motion jitter std (m, rad); see MotionConfig.validate


def _check_range(name: str, value: float, low: float, high: float,
                 low_open: bool = False, high_open: bool = False) -> None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    ok = (math.isfinite(number) and (number > low if low_open else number >= low)
          and (number < high if high_open else number <= high))
    if not ok:
        brackets = ("(" if low_open else "[", ")" if high_open else "]")
        raise ValueError(f"{name} = {value!r} is outside the allowed range {brackets[0]}{low}, {high}{brackets[1]}")


def _check_length(name: str, value: Any, length: int | None = None, meaning: str = "") -> tuple:
    """``value`` as a tuple of ``length`` entries (any non-zero length if None).

    A scalar or a wrong-length list is refused rather than broadcast: numpy would
    silently spread [1.0] over x, y and yaw, and [1.0, 1.0] fails only at the next
    reset, long after the parameter was accepted.
    """
    try:
        entries = tuple(value)
    except TypeError:
        entries = None
    if entries is None or (len(entries) != length if length is not None else not entries):
        expected = f"exactly {length} numbers" if length is not None else "at least one number"
        raise ValueError(f"{name} = {value!r} must be a list of {expected}{meaning}")
    return entries


def _check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name} = {value!r} is not one of {', '.join(choices)}")


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

    model: str = "bicycle"
    wheelbase: float = 4.0
    encoder_offset: float = 0.76
    sigma_speed: float = 0.5
    sigma_steering: float = math.pi / 60
    sigma_heading: float = 0.0
    noise_reference_period: float = 0.2
    odometry_translation_std: float = 0.01
    odometry_rotation_std: float = 0.002
    odometry_translation_per_meter: float = 0.05
    odometry_rotation_per_radian: float = 0.05
    odometry_rotation_per_meter: float = 0.01
    position_jitter: float = 1e-3
    heading_jitter: float = 1e-4
    max_step: float = 1.0
    max_prediction_interval: float = 1.0
    max_speed: float = 50.0
    max_yaw_rate: float = 10.0

    def validate(self, prefix: str = "motion") -> None:
        _check_choice(f"{prefix}.model", self.model, MOTION_MODELS)
        _check_range(f"{prefix}.wheelbase", self.wheelbase, 0.0, 100.0, low_open=True)
        _check_range(f"{prefix}.encoder_offset", self.encoder_offset, -10.0, 10.0)
        for name in ("sigma_speed", "sigma_steering", "sigma_heading",
                     "odometry_translation_std", "odometry_rotation_std",
                     "odometry_translation_per_meter", "odometry_rotation_per_radian",
                     "odometry_rotation_per_meter"):
            _check_range(f"{prefix}.{name}", getattr(self, name), 0.0, 100.0)
        _check_range(f"{prefix}.noise_reference_period", self.noise_reference_period, 0.0, 100.0, low_open=True)
        # The jitter keeps the step covariance positive definite: squared, a std of 1e-300
        # underflows to 0 and the Cholesky factorisation of the next step fails.
        _check_range(f"{prefix}.position_jitter", self.position_jitter, MIN_JITTER, 10.0)
        _check_range(f"{prefix}.heading_jitter", self.heading_jitter, MIN_JITTER, 1.0)
        _check_range(f"{prefix}.max_step", self.max_step, 0.0, 3600.0, low_open=True)
        _check_range(f"{prefix}.max_prediction_interval", self.max_prediction_interval, 0.0, 3600.0, low_open=True)
        _check_range(f"{prefix}.max_speed", self.max_speed, 0.0, 1e4, low_open=True)
        _check_range(f"{prefix}.max_yaw_rate", self.max_yaw_rate, 0.0, 1e3, low_open=True)


@dataclass
class SensorConfig:
    """Range-bearing sensor mounted at (offset_x, offset_y, offset_yaw) in the base frame."""

    offset_x: float = 0.0
    offset_y: float = 0.0
    offset_yaw: float = 0.0
    max_range: float = 30.0
    min_range: float = 0.0

    def validate(self, prefix: str = "sensor") -> None:
        for name in ("offset_x", "offset_y"):
            _check_range(f"{prefix}.{name}", getattr(self, name), -100.0, 100.0)
        _check_range(f"{prefix}.offset_yaw", self.offset_yaw, -math.pi, math.pi)
        _check_range(f"{prefix}.max_range", self.max_range, 0.0, 1e4, low_open=True)
        _check_range(f"{prefix}.min_range", self.min_range, 0.0, self.max_range)


@dataclass
class ObservationNoiseConfig:
    """Range-bearing noise W: Gaussian N(0, R) or the outlier-robust mixture.

    R = [[sigma_r^2, rho], [rho, sigma_b^2]] (seed notation: rho is the covariance
    term).  Mixture: sum_c weight_c N(0, scale_c R) (seed: 0.8 N(0,R) + 0.2 N(0,5R)).
    ``range_growth`` makes the range noise grow with range:
    sigma_r(range) = sigma_range + range_growth * range (thesis 003: context-dependent noise).
    """

    model: str = "gaussian"
    sigma_range: float = 0.5
    sigma_bearing: float = math.pi / 60
    rho: float = 0.01
    mixture_weights: tuple[float, ...] = (0.8, 0.2)
    mixture_scales: tuple[float, ...] = (1.0, 5.0)
    range_growth: float = 0.0

    def validate(self, prefix: str = "noise") -> None:
        _check_choice(f"{prefix}.model", self.model, NOISE_MODELS)
        _check_range(f"{prefix}.sigma_range", self.sigma_range, 0.0, 100.0, low_open=True)
        _check_range(f"{prefix}.sigma_bearing", self.sigma_bearing, 0.0, math.pi, low_open=True)
        limit = 0.999 * self.sigma_range * self.sigma_bearing
        _check_range(f"{prefix}.rho", self.rho, -limit, limit)
        _check_range(f"{prefix}.range_growth", self.range_growth, 0.0, 1.0)
        weights = _check_length(f"{prefix}.mixture_weights", self.mixture_weights)
        scales = _check_length(f"{prefix}.mixture_scales", self.mixture_scales)
        if len(weights) != len(scales):
            raise ValueError(f"{prefix}.mixture_weights and {prefix}.mixture_scales must have the same, non-zero length")
        # Each entry on its own: NaN compares False with everything, so a NaN weight
        # would pass the sum and sign tests below and give degenerate particle weights.
        for weight in weights:
            _check_range(f"{prefix}.mixture_weights", weight, 0.0, 1.0)
        for scale in scales:
            _check_range(f"{prefix}.mixture_scales", scale, 0.0, 1e6, low_open=True)
        if abs(math.fsum(float(w) for w in weights) - 1.0) > 1e-6:
            raise ValueError(f"{prefix}.mixture_weights = {self.mixture_weights} must be non-negative and sum to 1")


@dataclass
class FilterConfig:
    """Particle filter and the smoother that carries the E-step statistics."""

    num_particles: int = 100
    resample_threshold: float = 0.5
    smoother: str = "forward"
    paris_draws: int = 2
    seed: int | None = 0
    initial_pose_std: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def validate(self, prefix: str = "filter") -> None:
        _check_range(f"{prefix}.num_particles", self.num_particles, 1, 100000)
        _check_range(f"{prefix}.resample_threshold", self.resample_threshold, 0.0, 1.0)
        _check_choice(f"{prefix}.smoother", self.smoother, SMOOTHERS)
        _check_range(f"{prefix}.paris_draws", self.paris_draws, 1, 100)
        for std in _check_length(f"{prefix}.initial_pose_std", self.initial_pose_std, 3, " (x, y, yaw)"):
            _check_range(f"{prefix}.initial_pose_std", std, 0.0, 1e3)


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
    """

    algorithm: str = "online"
    step_size_exponent: float = 0.8
    min_updates_before_mstep: int = 1
    block_initial_length: int = 20
    block_growth: float = 1.1
    inflate_with_map_uncertainty: bool = False
    m_step: str = "observed"
    segment_length: int = 10
    relinearize_threshold: float = 0.5
    first_estimate_jacobians: bool = True

    def validate(self, prefix: str = "em") -> None:
        _check_choice(f"{prefix}.algorithm", self.algorithm, EM_ALGORITHMS)
        _check_range(f"{prefix}.step_size_exponent", self.step_size_exponent, 0.5, 1.0, low_open=True)
        _check_range(f"{prefix}.min_updates_before_mstep", self.min_updates_before_mstep, 1, 1000)
        _check_range(f"{prefix}.block_initial_length", self.block_initial_length, 1, 100000)
        _check_range(f"{prefix}.block_growth", self.block_growth, 0.0, 3.0)
        _check_choice(f"{prefix}.m_step", self.m_step, M_STEPS)
        _check_range(f"{prefix}.segment_length", self.segment_length, 1, 100000)
        _check_range(f"{prefix}.relinearize_threshold", self.relinearize_threshold, 0.0, 1e3, low_open=True)


@dataclass
class AssociationConfig:
    """Data association for observations with unknown id (-1).

    gate_probability:          chi-square(2) probability of the association gate.
    new_landmark_probability:  an observation outside this (wider) gate of every
                               landmark creates a landmark; between the two gates it
                               is ambiguous and dropped (counted).
    confirm_observations:      a tentative landmark becomes confirmed after this many
                               observations; unconfirmed ones older than
                               ``tentative_timeout`` observation steps are pruned.
    min_observations_for_weighting: landmarks seen fewer times do not weight particles.
    gate_position_std / gate_heading_std: extra pose uncertainty (m, rad) added to
                               the innovation covariance of the association gate only.
                               The particle cloud measures the pose relative to the map;
                               drift accumulated before a loop closure is not in it, and
                               without this margin a revisited landmark is created twice.
    max_observations_per_scan: usable points of one scan beyond this are dropped
                               (``too_many_observations``): a bound on the memory and
                               time one message can cost.
    """

    gate_probability: float = 0.99
    new_landmark_probability: float = 0.9999
    confirm_observations: int = 3
    tentative_timeout: int = 20
    min_observations_for_weighting: int = 2
    max_landmarks: int = 5000
    gate_position_std: float = 0.0
    gate_heading_std: float = 0.0
    max_observations_per_scan: int = 1000

    def validate(self, prefix: str = "association") -> None:
        # Both gates are chi-square quantiles: a probability of 1 is an infinite gate.
        _check_range(f"{prefix}.gate_probability", self.gate_probability, 0.0, 1.0,
                     low_open=True, high_open=True)
        _check_range(f"{prefix}.new_landmark_probability", self.new_landmark_probability,
                     self.gate_probability, 1.0, high_open=True)
        _check_range(f"{prefix}.confirm_observations", self.confirm_observations, 1, 1000)
        _check_range(f"{prefix}.tentative_timeout", self.tentative_timeout, 1, 1000000)
        _check_range(f"{prefix}.min_observations_for_weighting", self.min_observations_for_weighting, 1, 1000)
        _check_range(f"{prefix}.max_landmarks", self.max_landmarks, 1, 1000000)
        _check_range(f"{prefix}.gate_position_std", self.gate_position_std, 0.0, 100.0)
        _check_range(f"{prefix}.gate_heading_std", self.gate_heading_std, 0.0, 3.2)
        _check_range(f"{prefix}.max_observations_per_scan", self.max_observations_per_scan, 1, 100000)


LEARNABLE_NOISE = ("range", "bearing", "correlation", "mixture", "range_growth", "motion_scale")


@dataclass
class NoiseLearningConfig:
    """Online EM estimation of the noise parameters (docs/METHOD.md "Noise learned online", core/em/noise_learning.py).

    learn: the quantities estimated, a subset of ``LEARNABLE_NOISE``: ``range``
        (sigma_range), ``bearing`` (sigma_bearing), ``correlation`` (rho),
        ``mixture`` (weights and outlier scales; only with ``noise.model: mixture``),
        ``range_growth`` (sigma_r(r) = sigma_range + range_growth r; not by
        default: without range-dependent noise it trades off against
        sigma_range) and ``motion_scale`` (one factor on the whole motion noise
        covariance).
    step_size_exponent: gamma_n = n^-exponent (n counts observations) of the
        observation-noise statistics; below 1 the statistics computed under
        the first, wrong noise values are forgotten.
    motion_step_size_exponent: the same for the motion scale's statistic (n
        counts scans).  That statistic is a prediction error, valid whatever
        scale the filter used, so there is nothing to forget: 1 averages all
        of it (below 1 follows a motion noise that changes, e.g. with terrain).
    warmup_observations / warmup_steps: the learned observation noise is used
        after this many observations, the motion scale after this many scans.
    motion_window: filter steps over which the pose is predicted open loop for
        the motion scale's statistic (one step's motion noise is small next to
        the pose's uncertainty; L steps' is not).
    min_landmark_observations: observations of a landmark seen fewer times
        (this one included) are not used: its estimate is still the inverted
        first observation and its residual says little about R.
    *_limits: (floor, ceiling) of each learned value; correlation_limit bounds
        |rho| / (sigma_range sigma_bearing); mixture_weight_limits bound each
        outlier component's weight.
    """

    enabled: bool = False
    learn: tuple[str, ...] = ("range", "bearing", "correlation", "mixture", "motion_scale")
    step_size_exponent: float = 0.7
    motion_step_size_exponent: float = 1.0
    warmup_observations: int = 200
    warmup_steps: int = 50
    motion_window: int = 10
    min_landmark_observations: int = 5
    sigma_range_limits: tuple[float, float] = (0.01, 10.0)
    sigma_bearing_limits: tuple[float, float] = (0.001, 0.5)
    range_growth_limits: tuple[float, float] = (0.0, 0.5)
    correlation_limit: float = 0.9
    mixture_weight_limits: tuple[float, float] = (0.001, 0.5)
    mixture_scale_limits: tuple[float, float] = (2.0, 1000.0)
    motion_scale_limits: tuple[float, float] = (0.01, 100.0)

    def validate(self, prefix: str = "noise_learning") -> None:
        if isinstance(self.learn, str):
            raise ValueError(f"{prefix}.learn = {self.learn!r} must be a list of names of {', '.join(LEARNABLE_NOISE)}")
        for name in tuple(self.learn):
            _check_choice(f"{prefix}.learn", name, LEARNABLE_NOISE)
        _check_range(f"{prefix}.step_size_exponent", self.step_size_exponent, 0.5, 1.0, low_open=True)
        _check_range(f"{prefix}.motion_step_size_exponent", self.motion_step_size_exponent, 0.5, 1.0,
                     low_open=True)
        _check_range(f"{prefix}.warmup_observations", self.warmup_observations, 0, 10 ** 9)
        _check_range(f"{prefix}.warmup_steps", self.warmup_steps, 0, 10 ** 9)
        _check_range(f"{prefix}.motion_window", self.motion_window, 1, 1000)
        _check_range(f"{prefix}.min_landmark_observations", self.min_landmark_observations, 1, 10 ** 6)
        _check_range(f"{prefix}.correlation_limit", self.correlation_limit, 0.0, 0.99)
        # (name, lowest floor, highest ceiling, floor may be 0): the ceilings keep the
        # learned values inside what ObservationNoiseConfig / MotionConfig accept.
        for name, low, high, low_open in (("sigma_range_limits", 0.0, 100.0, True),
                                          ("sigma_bearing_limits", 0.0, math.pi, True),
                                          ("range_growth_limits", 0.0, 1.0, False),
                                          ("mixture_weight_limits", 0.0, 0.5, True),
                                          ("mixture_scale_limits", 1.0, 1e6, True),
                                          ("motion_scale_limits", 0.0, 1e4, True)):
            floor, ceiling = _check_length(f"{prefix}.{name}", getattr(self, name), 2, " (floor, ceiling)")
            _check_range(f"{prefix}.{name}", floor, low, high, low_open=low_open)
            _check_range(f"{prefix}.{name}", ceiling, float(floor), high)


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

