"""ROS parameters of the node: every core setting plus the node's own settings.

Core settings keep their dotted dataclass path as a flat parameter name
(``motion.model``, ``filter.num_particles``, ``noise.sigma_range`` ...), so the
YAML of the command-line tools and the node's parameter file read alike.
Every parameter gets a :class:`ParameterDescriptor` with a description and,
for numbers, the allowed range.  Values are checked twice: by rclpy against
the descriptor range (inclusive bounds), then as a whole by
:meth:`SlamConfig.validate` (open bounds and cross-field rules such as
``|rho| < sigma_range * sigma_bearing``) and the node-level rules below, so a
refused value always comes with a message naming the parameter and its range.

:func:`build` is pure (no rclpy): it turns a ``{name: value}`` dict into a
:class:`SlamConfig` and :class:`NodeSettings`, raising :class:`ParameterError`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:   # rcl_interfaces is imported where it is used, so build() works without ROS
    from rcl_interfaces.msg import ParameterDescriptor

from ..core.config import (EM_ALGORITHMS, M_STEPS, MOTION_MODELS, NOISE_MODELS, SMOOTHERS, SlamConfig)

AUTO_MODEL = "auto"
MOTION_SOURCES = ("odom", "control")
CONTROL_ANGULAR = ("steering", "yaw_rate")
RELIABILITIES = ("reliable", "best_effort")
STEERING_MODELS = ("bicycle", "acfr")
INT32_MAX = 2 ** 31 - 1


class ParameterError(ValueError):
    """A parameter value is refused; the message names the parameter and its allowed values."""


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False


# Core settings: description and (low, high) descriptor range (inclusive; open
# bounds and cross-field rules are enforced by SlamConfig.validate()).
_CORE = {
    "motion.model": ("Motion model: auto (from motion_source and control_angular: odom -> odometry, "
                     "control+steering -> bicycle, control+yaw_rate -> unicycle), bicycle, acfr, "
                     "unicycle or odometry.", None),
    "motion.wheelbase": ("Wheelbase B of the bicycle model / L of the acfr model (m), > 0.", (0.0, 100.0)),
    "motion.encoder_offset": ("acfr model: lateral offset H of the speed encoder (m).", (-10.0, 10.0)),
    "motion.sigma_speed": ("Speed noise std (m/s) over noise_reference_period.", (0.0, 100.0)),
    "motion.sigma_steering": ("Steering angle / yaw rate noise std (rad, rad/s) over noise_reference_period.",
                              (0.0, 100.0)),
    "motion.sigma_heading": ("Extra heading noise std (rad) over noise_reference_period.", (0.0, 100.0)),
    "motion.noise_reference_period": ("Period (s) the control noise stds refer to, > 0; scaled as white "
                                      "noise for other control periods.", (0.0, 100.0)),
    "motion.odometry_translation_std": ("Odometry model: translation noise std per step (m).", (0.0, 100.0)),
    "motion.odometry_rotation_std": ("Odometry model: rotation noise std per step (rad).", (0.0, 100.0)),
    "motion.odometry_translation_per_meter": ("Odometry model: translation noise std per metre driven.",
                                              (0.0, 100.0)),
    "motion.odometry_rotation_per_radian": ("Odometry model: rotation noise std per radian turned.",
                                            (0.0, 100.0)),
    "motion.odometry_rotation_per_meter": ("Odometry model: rotation noise std (rad) per metre driven.",
                                           (0.0, 100.0)),
    "motion.position_jitter": ("Position jitter std (m) added per step, >= 1e-9 (keeps particles diverse "
                               "and the step covariance positive definite).", (1e-9, 10.0)),
    "motion.heading_jitter": ("Heading jitter std (rad) added per step, >= 1e-9.", (1e-9, 1.0)),
    "motion.max_step": ("Longest motion step integrated at once (s), > 0; longer gaps are clipped "
                        "and counted (large_time_step_clipped).", (0.0, 3600.0)),
    "motion.max_prediction_interval": ("A filter step without observations runs after this many seconds "
                                       "of motion only (s), > 0.", (0.0, 3600.0)),
    "sensor.offset_x": ("Sensor mount x in the base frame (m).", (-100.0, 100.0)),
    "sensor.offset_y": ("Sensor mount y in the base frame (m).", (-100.0, 100.0)),
    "sensor.offset_yaw": ("Sensor mount yaw in the base frame (rad).", (-math.pi, math.pi)),
    "sensor.max_range": ("Observations farther than this are dropped (m), > 0.", (0.0, 1e4)),
    "sensor.min_range": ("Observations nearer than this are dropped (m), <= sensor.max_range.", (0.0, 1e4)),
    "noise.model": ("Observation noise: gaussian N(0,R) or mixture sum_c w_c N(0, s_c R) (outlier-robust).",
                    None),
    "noise.sigma_range": ("Range noise std sigma_r (m), > 0.", (0.0, 100.0)),
    "noise.sigma_bearing": ("Bearing noise std sigma_b (rad), > 0.", (0.0, math.pi)),
    "noise.rho": ("Range-bearing covariance term of R (m rad); |rho| < 0.999 sigma_range sigma_bearing.", None),
    "noise.mixture_weights": ("Mixture component weights (non-negative, sum 1).", None),
    "noise.mixture_scales": ("Mixture component covariance scales (positive, as many as weights).", None),
    "noise.range_growth": ("Range std grows by this times the range: sigma_r + growth * range.", (0.0, 1.0)),
    "filter.num_particles": ("Number of particles N.", (1, 100000)),
    "filter.resample_threshold": ("Resample when ESS < threshold * N.", (0.0, 1.0)),
    "filter.smoother": ("Sufficient-statistics smoother: forward, paris or ancestry.", None),
    "filter.paris_draws": ("PaRIS backward draws per particle.", (1, 100)),
    "filter.seed": ("Random seed; -1 draws a fresh seed.", (-1, INT32_MAX)),
    "filter.initial_pose_std": ("Std of the initial particle cloud: exactly 3 values (x m, y m, yaw rad).",
                                None),
    "em.algorithm": ("online (stochastic approximation), block or block_averaged (Block Online EM).", None),
    "em.step_size_exponent": ("Online EM step size gamma_n = n^-exponent, in (0.5, 1].", (0.5, 1.0)),
    "em.min_updates_before_mstep": ("EM updates of a landmark before its M-step.", (1, 1000)),
    "em.block_initial_length": ("Block Online EM: first block length (steps).", (1, 100000)),
    "em.block_growth": ("Block Online EM: block k has length initial * k^growth.", (0.0, 3.0)),
    "em.inflate_with_map_uncertainty": ("Add the landmark covariance to the innovation covariance.", None),
    "em.m_step": ("complete (seed: A^-1 b per landmark) or observed (Newton step with the observed "
                  "information: poses integrated out of the joint system).", None),
    "em.segment_length": ("Observed M-step: filter steps per segment whose poses are integrated out.",
                          (1, 100000)),
    "em.relinearize_threshold": ("Observed M-step: a landmark farther than this (m) from its first "
                                 "estimate gets new Jacobians for its next factors.", (0.0, 1000.0)),
    "em.first_estimate_jacobians": ("Observed M-step: Jacobians at each variable's first estimate, so the "
                                    "map's orientation gains no false information (FEJ).", None),
    "association.gate_probability": ("Chi-square(2) probability of the association gate, in (0, 1).",
                                     (0.0, 1.0)),
    "association.new_landmark_probability": ("Outside this wider gate of every landmark an unknown-id "
                                             "observation creates a landmark; in [gate_probability, 1).",
                                             (0.0, 1.0)),
    "association.confirm_observations": ("Observations that confirm a tentative landmark.", (1, 1000)),
    "association.tentative_timeout": ("Unconfirmed landmarks older than this many steps are pruned.",
                                      (1, 1000000)),
    "association.min_observations_for_weighting": ("Landmarks seen fewer times do not weight particles.",
                                                   (1, 1000)),
    "association.max_landmarks": ("Map size limit; further new landmarks are dropped (map_full).",
                                  (1, 1000000)),
    "association.gate_position_std": ("Extra pose position std (m) in the association gate only: drift "
                                      "accumulated before a loop closure, so revisited landmarks are "
                                      "re-associated instead of duplicated.", (0.0, 100.0)),
    "association.gate_heading_std": ("Extra heading std (rad) in the association gate only.", (0.0, 3.2)),
    "association.max_observations_per_scan": ("Usable points of one scan beyond this are dropped "
                                              "(too_many_observations).", (1, 100000)),
    "motion.max_speed": ("Controls or odometry increments faster than this (m/s) are physically "
                         "impossible: dropped and counted.", (0.0, 1e4)),
    "motion.max_yaw_rate": ("Yaw rates beyond this (rad/s) are physically impossible: dropped and "
                            "counted.", (0.0, 1e3)),
    "noise_learning.enabled": ("Learn the noise online by EM (noise_learning.learn); the learned values "
                               "are used once warmed up and shown on /diagnostics.", None),
    "noise_learning.learn": ("Quantities learned: any of range, bearing, correlation, mixture (with "
                             "noise.model mixture), range_growth, motion_scale. To learn nothing set "
                             "enabled false.", None),
    "noise_learning.step_size_exponent": ("Step size gamma_n = n^-exponent of the noise statistics, in "
                                          "(0.5, 1].", (0.5, 1.0)),
    "noise_learning.motion_step_size_exponent": ("Step size exponent of the motion scale's statistic, in "
                                                 "(0.5, 1]; 1 averages it all (it is valid under any scale).",
                                                 (0.5, 1.0)),
    "noise_learning.warmup_observations": ("Observations before the learned observation noise is used.",
                                           (0, 1000000000)),
    "noise_learning.warmup_steps": ("Scans (motion statistics) before the learned motion scale is used.",
                                    (0, 1000000000)),
    "noise_learning.motion_window": ("Filter steps over which the pose is predicted open loop for the motion "
                                     "scale's statistic.", (1, 1000)),
    "noise_learning.min_landmark_observations": ("Observations of landmarks seen fewer times (this one "
                                                 "included) do not inform R.", (1, 1000000)),
    "noise_learning.sigma_range_limits": ("Floor and ceiling of the learned sigma_range (m), 0 < floor <= "
                                          "ceiling <= 100.", None),
    "noise_learning.sigma_bearing_limits": ("Floor and ceiling of the learned sigma_bearing (rad), 0 < floor "
                                            "<= ceiling <= pi.", None),
    "noise_learning.range_growth_limits": ("Floor and ceiling of the learned range_growth, in [0, 1].", None),
    "noise_learning.correlation_limit": ("Bound on |rho| / (sigma_range sigma_bearing) when learned.",
                                         (0.0, 0.99)),
    "noise_learning.mixture_weight_limits": ("Floor and ceiling of each learned outlier weight, in (0, 0.5].",
                                             None),
    "noise_learning.mixture_scale_limits": ("Floor and ceiling of each learned outlier scale, 1 < floor <= "
                                            "ceiling <= 1e6.", None),
    "noise_learning.motion_scale_limits": ("Floor and ceiling of the learned motion noise scale (factor on "
                                           "the motion covariance), 0 < floor <= ceiling <= 1e4.", None),
}

_CHOICES = {
    "motion.model": (AUTO_MODEL,) + MOTION_MODELS,
    "noise.model": NOISE_MODELS,
    "filter.smoother": SMOOTHERS,
    "em.algorithm": EM_ALGORITHMS,
    "em.m_step": M_STEPS,
}

# Node settings: (name, default, description, range or choices, read_only).
NODE_SPECS = (
    ParamSpec("map_frame", "map", "Frame of the map and of the published pose."),
    ParamSpec("odom_frame", "odom", "Odometry frame; the node publishes map -> odom."),
    ParamSpec("base_frame", "base_link", "Robot base frame (child of the odometry messages)."),
    ParamSpec("sensor_frame", "", "Frame of the observation clouds; clouds in another frame (other than "
              "base_frame) are used but counted and warned about. Empty: any frame but map_frame and odom_frame."),
    ParamSpec("publish_tf", True, "Publish map -> odom (disable when another node owns it)."),
    ParamSpec("transform_publish_period", 0.05, "Republish map -> odom every this many seconds "
              "(0: only after updates).", 0.0, 10.0, read_only=True),
    ParamSpec("transform_timeout", 0.2, "map -> odom is stamped this far in the future (s).", 0.0, 10.0),
    ParamSpec("map_publish_period", 1.0, "Landmark map, markers and path publish period (s, > 0).",
              0.001, 3600.0, read_only=True),
    ParamSpec("diagnostics_period", 1.0, "Period of /diagnostics (s, > 0).", 0.01, 3600.0, read_only=True),
    ParamSpec("path_max_length", 10000, "Poses kept for ~/path (0: no path); 32 bytes each.", 0, 1000000),
    ParamSpec("path_publish_max_poses", 1000, "~/path holds at most this many of the kept poses (evenly "
              "spaced, always the newest): bounds the cost of a publish (about 20 ms per 1000 poses).",
              2, 20000),
    ParamSpec("publish_particles", True, "Publish ~/particles after each observation update."),
    ParamSpec("motion_source", "odom", "Motion input: odom (nav_msgs/Odometry, odometry model) or "
              "control (geometry_msgs/TwistStamped).", choices=MOTION_SOURCES, read_only=True),
    ParamSpec("control_angular", "steering", "Meaning of twist.angular.z on the control topic: steering "
              "angle (rad; bicycle/acfr) or yaw rate (rad/s; unicycle).", choices=CONTROL_ANGULAR,
              read_only=True),
    ParamSpec("odom_topic", "odom", "Odometry input topic.", read_only=True),
    ParamSpec("control_topic", "control", "Control input topic (TwistStamped).", read_only=True),
    ParamSpec("observations_topic", "landmark_observations", "Range-bearing observations topic "
              "(PointCloud2 with fields range, bearing; optional id, range_std, bearing_std).",
              read_only=True),
    ParamSpec("input_qos.reliability", "best_effort", "Input subscriptions: best_effort (KEEP_LAST "
              "input_qos.depth; matches every publisher, as REP-2003 sensor inputs) or reliable (KEEP_ALL: "
              "lossless bag replay, a full queue makes the reliable publisher wait; needs reliable "
              "publishers).", choices=RELIABILITIES, read_only=True),
    ParamSpec("input_qos.depth", 1000, "Input queue depth (best_effort; the resource hint of reliable).",
              1, 100000, read_only=True),
    ParamSpec("input_delay", 1.0, "Inputs are processed in stamp order: each waits until every active "
              "input stream has delivered a message at least as recent (lossless at any replay rate); a "
              "stream silent for this long (wall-clock s) stops holding the others back. Must exceed the "
              "slowest input period (0: process each input on arrival).", 0.0, 10.0),
    ParamSpec("reset_on_time_jump", True, "Reset when the clock or the input stamps jump back."),
    ParamSpec("time_jump_threshold", 1.0, "A backward jump of more than this (s) resets; smaller "
              "backward steps are dropped as out_of_order.", 0.01, 1e6, read_only=True),
    ParamSpec("map_file", "~/.ros/online_em_slam_map.npz", "File of ~/save_map and ~/load_map; relative to "
              "map_directory, and must lie inside it ('..' and symlinks out of it are refused). Read-only "
              "at run time: any DDS participant could otherwise make ~/save_map overwrite files.",
              read_only=True),
    ParamSpec("map_directory", "", "Directory ~/save_map and ~/load_map are confined to (created by "
              "~/save_map if missing; nothing outside it is). Empty: the directory of map_file.",
              read_only=True),
    ParamSpec("load_map_on_start", False, "Load map_file at start-up."),
    ParamSpec("initial_pose.x", 0.0, "Initial pose x in the map frame (m).", -1e7, 1e7),
    ParamSpec("initial_pose.y", 0.0, "Initial pose y in the map frame (m).", -1e7, 1e7),
    ParamSpec("initial_pose.yaw", 0.0, "Initial pose yaw in the map frame (rad).", -math.pi, math.pi),
    ParamSpec("warn_throttle_period", 5.0, "Minimum period (s) between repeated warnings of one kind.",
              0.0, 3600.0, read_only=True),
    ParamSpec("marker_sigma", 2.0, "Covariance ellipses of ~/landmark_markers are drawn at this many "
              "standard deviations.", 0.1, 10.0),
)


@dataclass
class NodeSettings:
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    sensor_frame: str = ""
    publish_tf: bool = True
    transform_publish_period: float = 0.05
    transform_timeout: float = 0.2
    map_publish_period: float = 1.0
    diagnostics_period: float = 1.0
    path_max_length: int = 10000
    path_publish_max_poses: int = 1000
    publish_particles: bool = True
    motion_source: str = "odom"
    control_angular: str = "steering"
    odom_topic: str = "odom"
    control_topic: str = "control"
    observations_topic: str = "landmark_observations"
    input_reliability: str = "best_effort"
    input_depth: int = 1000
    input_delay: float = 1.0
    reset_on_time_jump: bool = True
    time_jump_threshold: float = 1.0
    map_file: str = ""
    map_directory: str = ""
    load_map_on_start: bool = False
    initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    warn_throttle_period: float = 5.0
    marker_sigma: float = 2.0


def _core_defaults() -> dict[str, Any]:
    defaults = {}
    config = SlamConfig()
    for section in fields(config):
        sub = getattr(config, section.name)
        for f in fields(sub):
            value = getattr(sub, f.name)
            name = f"{section.name}.{f.name}"
            if name == "motion.model":
                value = AUTO_MODEL
            elif name == "filter.seed":
                value = -1 if value is None else int(value)
            elif isinstance(value, tuple):
                # Lists of names (noise_learning.learn) stay strings; numbers are doubles.
                value = [v if isinstance(v, str) else float(v) for v in value]
            defaults[name] = value
    return defaults


def core_specs() -> list[ParamSpec]:
    """One spec per field of SlamConfig (fields unknown to the table still get a parameter)."""
    specs = []
    for name, default in _core_defaults().items():
        description, bounds = _CORE.get(name, (f"Core setting {name} (see online_em_slam/core/config.py).",
                                               None))
        low, high = bounds if bounds else (None, None)
        specs.append(ParamSpec(name, default, description, low, high, _CHOICES.get(name)))
    return specs


def all_specs() -> list[ParamSpec]:
    return core_specs() + list(NODE_SPECS)


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """ParameterDescriptor with type, description, range and choices of ``spec``."""
    from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,  # noqa: PLC0415
                                    ParameterDescriptor, ParameterType)
    d = ParameterDescriptor(name=spec.name, description=spec.description, read_only=spec.read_only)
    value = spec.default
    if isinstance(value, bool):
        d.type = ParameterType.PARAMETER_BOOL
    elif isinstance(value, int):
        d.type = ParameterType.PARAMETER_INTEGER
        if spec.low is not None:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
            d.additional_constraints = f"integer in [{int(spec.low)}, {int(spec.high)}]"
    elif isinstance(value, float):
        d.type = ParameterType.PARAMETER_DOUBLE
        if spec.low is not None:
            d.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high),
                                                         step=0.0)]
            d.additional_constraints = f"in [{spec.low:g}, {spec.high:g}] (see description for open bounds)"
    elif isinstance(value, str):
        d.type = ParameterType.PARAMETER_STRING
        if spec.choices:
            d.additional_constraints = "one of: " + ", ".join(spec.choices)
    elif isinstance(value, list):
        strings = bool(value) and isinstance(value[0], str)          # noise_learning.learn
        d.type = ParameterType.PARAMETER_STRING_ARRAY if strings else ParameterType.PARAMETER_DOUBLE_ARRAY
    return d


def declare_parameters(node) -> None:
    """Declare every parameter on ``node`` (start-up overrides are applied by rclpy).

    An override outside the descriptor range or of the wrong type raises
    ParameterError naming the parameter.
    """
    from rclpy.exceptions import ParameterException  # noqa: PLC0415 (keep build() importable alone)
    for spec in all_specs():
        try:
            node.declare_parameter(spec.name, spec.default, descriptor(spec))
        except ParameterException as error:
            message = str(error).removesuffix(f": {spec.name}")
            raise ParameterError(f"invalid parameter {spec.name}: {message}") from None


def current_values(node) -> dict[str, Any]:
    return {spec.name: node.get_parameter(spec.name).value for spec in all_specs()}


def defaults() -> dict[str, Any]:
    return {spec.name: spec.default for spec in all_specs()}


def resolve_motion_model(model: str, motion_source: str, control_angular: str) -> str:
    """The core motion model implied by the node's motion settings (or refuse a contradiction)."""
    if motion_source == "odom":
        wanted = ("odometry",)
    else:
        wanted = STEERING_MODELS if control_angular == "steering" else ("unicycle",)
    if model == AUTO_MODEL:
        return wanted[0]
    if model not in wanted:
        raise ParameterError(
            f"motion.model = {model!r} contradicts motion_source = {motion_source!r} and control_angular = "
            f"{control_angular!r}: use one of {', '.join((AUTO_MODEL,) + wanted)}")
    return model


def _check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ParameterError(f"{name} = {value!r} is not one of {', '.join(choices)}")


def _check_range(name: str, value: Any, low: float, high: float) -> None:
    try:
        ok = math.isfinite(float(value)) and low <= float(value) <= high
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"{name} = {value!r} is outside the allowed range [{low:g}, {high:g}]")


def build(values: dict[str, Any]) -> tuple[SlamConfig, NodeSettings]:
    """SlamConfig and NodeSettings from flat parameter values; ParameterError names the culprit."""
    merged = defaults()
    merged.update(values)
    # Node settings first (motion.model depends on them).
    for spec in NODE_SPECS:
        value = merged[spec.name]
        if spec.choices:
            _check_choice(spec.name, value, spec.choices)
        elif spec.low is not None:
            _check_range(spec.name, value, spec.low, spec.high)
    for spec in core_specs():
        if spec.choices:
            _check_choice(spec.name, merged[spec.name], spec.choices)
    settings = NodeSettings(
        map_frame=str(merged["map_frame"]), odom_frame=str(merged["odom_frame"]),
        base_frame=str(merged["base_frame"]), sensor_frame=str(merged["sensor_frame"]),
        publish_tf=bool(merged["publish_tf"]),
        transform_publish_period=float(merged["transform_publish_period"]),
        transform_timeout=float(merged["transform_timeout"]),
        map_publish_period=float(merged["map_publish_period"]),
        diagnostics_period=float(merged["diagnostics_period"]),
        path_max_length=int(merged["path_max_length"]),
        path_publish_max_poses=int(merged["path_publish_max_poses"]),
        publish_particles=bool(merged["publish_particles"]),
        motion_source=str(merged["motion_source"]), control_angular=str(merged["control_angular"]),
        odom_topic=str(merged["odom_topic"]), control_topic=str(merged["control_topic"]),
        observations_topic=str(merged["observations_topic"]),
        input_reliability=str(merged["input_qos.reliability"]), input_depth=int(merged["input_qos.depth"]),
        input_delay=float(merged["input_delay"]), reset_on_time_jump=bool(merged["reset_on_time_jump"]),
        time_jump_threshold=float(merged["time_jump_threshold"]), map_file=str(merged["map_file"]),
        map_directory=str(merged["map_directory"]),
        load_map_on_start=bool(merged["load_map_on_start"]),
        initial_pose=(float(merged["initial_pose.x"]), float(merged["initial_pose.y"]),
                      float(merged["initial_pose.yaw"])),
        warn_throttle_period=float(merged["warn_throttle_period"]),
        marker_sigma=float(merged["marker_sigma"]),
    )
    for name in ("map_frame", "odom_frame", "base_frame", "odom_topic", "control_topic", "observations_topic"):
        if not getattr(settings, name).strip():
            raise ParameterError(f"{name} must not be empty")
    if len({settings.map_frame, settings.odom_frame, settings.base_frame}) < 3:
        raise ParameterError(f"map_frame, odom_frame and base_frame must differ (got {settings.map_frame!r}, "
                             f"{settings.odom_frame!r}, {settings.base_frame!r})")

    nested: dict[str, dict[str, Any]] = {}
    for name, value in merged.items():
        section, _, key = name.partition(".")
        if section not in {f.name for f in fields(SlamConfig)}:
            continue
        if name == "motion.model":
            value = resolve_motion_model(value, settings.motion_source, settings.control_angular)
        elif name == "filter.seed":
            value = None if int(value) < 0 else int(value)
        nested.setdefault(section, {})[key] = value
    try:
        config = SlamConfig.from_dict(nested)
    except (ValueError, TypeError) as error:
        raise ParameterError(str(error)) from None
    return config, settings
