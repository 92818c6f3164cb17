"""ROS parameters of the node: every core setting plus the node's own settings.

Core settings keep their dotted dataclass path as a flat parameter name
(``motion.model``, ``filter.num_particles``, ``noise.sigma_range`` ...), so the
YAML of the command-line tools and the node's parameter file read alike.
Every parameter gets a :class:`ParameterDescriptor` with a description and,
for numbers, the allowed range.  The core parameters' specs are derived from
the field metadata of core/config.py (:func:`core_specs`; description, range,
open bounds, choices written once there); the node's own are ``NODE_SPECS``,
and :class:`NodeSettings` is read from them by name.  Values are checked twice:
by rclpy against the descriptor range (inclusive bounds), then as a whole by
:meth:`SlamConfig.validate` (the same ranges with their open bounds, and
cross-field rules such as ``|rho| < sigma_range * sigma_bearing``) and the
node-level rules below, so a refused value always comes with a message naming
the parameter and its range.

:func:`build` is pure (no rclpy): it turns a ``{name: value}`` dict into a
:class:`SlamConfig` and :class:`NodeSettings`, raising :class:`ParameterError`.
"""
from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:   # rcl_interfaces is imported where it is used, so build() works without ROS
    from rcl_interfaces.msg import ParameterDescriptor

from ..core.config import MOTION_MODELS, SlamConfig, core_parameters

AUTO_MODEL = "auto"
MOTION_SOURCES = ("odom", "control")
CONTROL_ANGULAR = ("steering", "yaw_rate")
RELIABILITIES = ("reliable", "best_effort")
STEERING_MODELS = ("bicycle", "acfr")


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
    low_open: bool = False          # low itself is refused (by SlamConfig.validate; rclpy ranges are inclusive)
    high_open: bool = False


# Core settings whose parameter differs from the core's value: the node resolves
# motion.model "auto" from motion_source and control_angular, and -1 is filter.seed None.
_ROS_ENCODING = {
    "motion.model": {"default": AUTO_MODEL, "choices": (AUTO_MODEL,) + MOTION_MODELS,
                     "description": "Motion model: auto (from motion_source and control_angular: odom -> "
                                    "odometry, control+steering -> bicycle, control+yaw_rate -> unicycle), "
                                    "bicycle, acfr, unicycle or odometry."},
    "filter.seed": {"low": -1, "description": "Random seed; -1 draws a fresh seed."},
    # The core's defaults are the seed experiment's (the simulation and the benchmark give
    # the true noise).  On a robot the noise is unknown: the node and `online-em-slam run`
    # learn it, under the heavy-tailed model that survives detections with heavy tails
    # (docs/RESULTS.md, "Noise learned online": the Gaussian fails on Victoria Park).
    "noise.model": {"default": "student_t"},
    "noise_learning.enabled": {"default": True},
}

# Node settings: (name, default, description, range or choices, read_only).
NODE_SPECS = (
    ParamSpec("map_frame", "map", "Frame of the map and of the published pose."),
    ParamSpec("odom_frame", "odom", "Odometry frame; the node publishes map -> odom."),
    ParamSpec("base_frame", "base_link", "Robot base frame (child of the odometry messages)."),
    ParamSpec("sensor_frame", "", "Frame of the observation clouds; clouds in another frame (other than "
              "base_frame, or one TF resolves when tf2_ros is importable) are used but counted and warned about. "
              "Empty: any frame but map_frame and odom_frame."),
    ParamSpec("autostart", True, "Configure and activate the lifecycle node at start (false: wait for a "
              "lifecycle manager or ros2 lifecycle set).", read_only=True),
    ParamSpec("publish_tf", True, "Publish map -> odom (disable when another node owns it)."),
    ParamSpec("transform_publish_period", 0.05, "Republish map -> odom every this many seconds "
              "(0: only after updates).", 0.0, 10.0, read_only=True),
    ParamSpec("transform_timeout", 0.2, "map -> odom is stamped this far in the future (s).", 0.0, 10.0),
    ParamSpec("map_publish_period", 1.0, "Landmark map, markers and path publish period (s, > 0).",
              0.001, 3600.0, read_only=True),
    ParamSpec("diagnostics_period", 1.0, "Period of /diagnostics (s, > 0).", 0.01, 3600.0, read_only=True),
    ParamSpec("input_timeout", 10.0, "/diagnostics turns ERROR when inputs flowed and then every subscribed "
              "input has been silent this long (s; 0: never).", 0.0, 86400.0),
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
    ParamSpec("input_max_wait", 0.25, "Best-effort inputs: an observation cloud that waited longer than this "
              "(wall-clock s) in its subscription's queue is shed unread (dropped.overload), so that the "
              "motion inputs, never shed, keep up and the estimate lags the inputs by about this much at most "
              "(0: shed by load alone).", 0.0, 60.0),
    ParamSpec("input_delay", 1.0, "Inputs are processed in stamp order: each waits until every active "
              "input stream has delivered a message at least as recent (lossless at any replay rate); a "
              "stream silent for this long (wall-clock s) stops holding the others back. Must exceed the "
              "slowest input period (0: process each input on arrival).", 0.0, 10.0),
    ParamSpec("reset_on_time_jump", True, "Restart the pose and the time line (keeping the map) when the clock "
              "or the input stamps jump back."),
    ParamSpec("time_jump_threshold", 1.0, "A backward jump of more than this (s), once confirmed, restarts the "
              "pose and the time line (the map stays); smaller backward steps are dropped as out_of_order.",
              0.01, 1e6, read_only=True),
    ParamSpec("map_file", "~/.ros/online_em_slam_map.npz", "File of ~/save_map_file and ~/load_map_file, "
              "and of ~/save_map and ~/load_map called without a file; relative to map_directory, and must "
              "lie inside it ('..' and symlinks out of it are refused). Read-only at run time: any DDS "
              "participant could otherwise make ~/save_map overwrite files.",
              read_only=True),
    ParamSpec("map_directory", "", "Directory every map file of ~/save_map and ~/load_map (a file name "
              "per call) is confined to (created by ~/save_map if missing; nothing outside it is). Empty: "
              "the directory of map_file.",
              read_only=True),
    ParamSpec("load_map_on_start", False, "Load map_file at start-up."),
    ParamSpec("initial_pose.x", 0.0, "Initial pose x in the map frame (m).", -1e7, 1e7),
    ParamSpec("initial_pose.y", 0.0, "Initial pose y in the map frame (m).", -1e7, 1e7),
    ParamSpec("initial_pose.yaw", 0.0, "Initial pose yaw in the map frame (rad).", -math.pi, math.pi),
    ParamSpec("robots", [], "Fleet mode: the robots' namespaces (robot1, robot2, ...); each robot's inputs are "
              "<robot>/<odom_topic|control_topic|observations_topic>, its outputs <robot>/pose, <robot>/path, "
              "<robot>/particles and map -> <robot>/<odom_frame>; one map for all. Empty: one robot, the "
              "node's own topics.", read_only=True),
    ParamSpec("initial_poses", [], "Fleet mode: x, y, yaw of each robot in the map frame, robot after robot "
              "(3 per robot, as initial_pose.*). Empty: every robot starts at initial_pose.*.", read_only=True),
    ParamSpec("local_robot", "", "Distributed fleet mode: the one robot of robots this node drives (its inputs "
              "and outputs only); the node shares the map with the other robots' nodes over segments_topic. "
              "Empty: this node drives every robot of robots.", read_only=True),
    ParamSpec("segments_topic", "/fleet/map_segments", "Distributed fleet mode: the topic (std_msgs/"
              "UInt8MultiArray, reliable, transient local) on which the nodes exchange their robots' map "
              "information, one closed segment per message.", read_only=True),
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
    autostart: bool = True
    publish_tf: bool = True
    transform_publish_period: float = 0.05
    transform_timeout: float = 0.2
    map_publish_period: float = 1.0
    diagnostics_period: float = 1.0
    input_timeout: float = 10.0
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
    input_max_wait: float = 0.25
    input_delay: float = 1.0
    reset_on_time_jump: bool = True
    time_jump_threshold: float = 1.0
    map_file: str = ""
    map_directory: str = ""
    load_map_on_start: bool = False
    initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    robots: tuple[str, ...] = ()
    initial_poses: tuple[float, ...] = ()
    local_robot: str = ""
    segments_topic: str = "/fleet/map_segments"
    warn_throttle_period: float = 5.0
    marker_sigma: float = 2.0


def _parameter_value(value: Any) -> Any:
    """A core default as a parameter value: tuples become lists, of names (noise_learning.learn)
    or of doubles; None (filter.seed, optional) is -1."""
    if value is None:
        return -1
    if isinstance(value, tuple):
        return [v if isinstance(v, str) else float(v) for v in value]
    return value


def core_specs() -> list[ParamSpec]:
    """One spec per field of SlamConfig, from the field's metadata (core/config.py ``param``):
    description, range (open bounds included) and choices are written there once."""
    specs = []
    for name, default, info in core_parameters():
        spec = ParamSpec(name, _parameter_value(default), info.doc, info.lo, info.hi, info.choices,
                         low_open=info.lo_open, high_open=info.hi_open)
        specs.append(replace(spec, **_ROS_ENCODING.get(name, {})))
    return specs


def all_specs() -> list[ParamSpec]:
    return core_specs() + list(NODE_SPECS)


def bound_text(value: float) -> str:
    """Whole numbers in full below 1e7 (1000000, not 1e+06), others as %g."""
    if float(value).is_integer() and abs(value) < 1e7:
        return str(int(value))
    return f"{value:g}"


def range_text(spec: ParamSpec) -> str | None:
    """'(0, 100]' (open bounds as SlamConfig.validate applies them), or None without a range."""
    if spec.low is None or spec.high is None:
        return None
    return (f"{'(' if spec.low_open else '['}{bound_text(spec.low)}, {bound_text(spec.high)}"
            f"{')' if spec.high_open else ']'}")


def constraint_text(spec: ParamSpec) -> str | None:
    """The descriptor's additional_constraints: 'in (0, 100]', 'each entry in [0, 1000]', 'one of: ...'."""
    each = "each entry " if isinstance(spec.default, list) else ""
    if spec.choices:
        return f"{each}one of: " + ", ".join(spec.choices)
    interval = range_text(spec)
    if interval is None:
        return None
    return f"{each}{'integer ' if type(spec.default) is int else ''}in {interval}"


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """ParameterDescriptor with type, description, range and choices of ``spec``.

    rclpy enforces the (inclusive) range of a number; open bounds, entries of
    arrays and choices are stated in additional_constraints and enforced by build().
    """
    from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,  # noqa: PLC0415
                                    ParameterDescriptor, ParameterType)
    d = ParameterDescriptor(name=spec.name, description=spec.description, read_only=spec.read_only)
    d.additional_constraints = constraint_text(spec) or ""
    value = spec.default
    if isinstance(value, bool):
        d.type = ParameterType.PARAMETER_BOOL
    elif isinstance(value, int):
        d.type = ParameterType.PARAMETER_INTEGER
        if spec.low is not None:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    elif isinstance(value, float):
        d.type = ParameterType.PARAMETER_DOUBLE
        if spec.low is not None:
            d.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high),
                                                         step=0.0)]
    elif isinstance(value, str):
        d.type = ParameterType.PARAMETER_STRING
    elif isinstance(value, list):
        strings = bool(value) and isinstance(value[0], str)          # noise_learning.learn
        d.dynamic_typing = not value       # an empty default has no element type (robots): build() checks it
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


# Parameters ROS itself reads on every node (rclpy declares them, or reads them when it creates a
# publisher or subscription): a parameter file may set them, and they are not unknown.
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service", "start_parameter_services",
                  "start_parameter_event_publisher")
ROS_PARAMETER_PREFIXES = ("qos_overrides.",)


def is_ros_parameter(name: str) -> bool:
    return name in ROS_PARAMETERS or name.startswith(ROS_PARAMETER_PREFIXES)


def check_names(names) -> None:
    """Refuse parameter names that are neither the node's nor ROS's own: one ParameterError for
    all of them, each with the nearest valid name (a typo such as filter.num_partcles).
    The node (its start-up overrides) and the offline runner (its parameter files) both apply it."""
    valid = [spec.name for spec in all_specs()]
    known = set(valid)
    unknown = sorted(str(name) for name in names if name not in known and not is_ros_parameter(str(name)))
    if not unknown:
        return
    parts = []
    for name in unknown:
        nearest = difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
        parts.append(f"{name} (did you mean {nearest[0]}?)" if nearest else name)
    raise ParameterError(f"unknown parameter{'s' if len(unknown) > 1 else ''}: {', '.join(parts)}")


def as_declared_type(spec: ParamSpec, value: Any) -> Any:
    """An integer where the spec is a double (or integers in a double array) as float, as the
    offline runner reads them; other values unchanged (rclpy then refuses a wrong type)."""
    if isinstance(spec.default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if (isinstance(spec.default, list) and not (spec.default and isinstance(spec.default[0], str))
            and isinstance(value, (list, tuple)) and value
            and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        return [float(v) for v in value]
    return value


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


# NodeSettings fields read from a parameter of another name (initial_pose: three);
# every other field is the parameter of its own name, converted to the field's type.
SETTING_PARAMETERS = {"input_reliability": "input_qos.reliability", "input_depth": "input_qos.depth",
                       "initial_pose": ("initial_pose.x", "initial_pose.y", "initial_pose.yaw")}


def _node_settings(merged: dict[str, Any]) -> NodeSettings:
    """NodeSettings from the checked node parameters (NODE_SPECS), plus the rules across them."""
    values = {}
    for f in fields(NodeSettings):
        source = SETTING_PARAMETERS.get(f.name, f.name)
        if isinstance(source, tuple):
            values[f.name] = tuple(float(merged[name]) for name in source)
        else:
            values[f.name] = type(f.default)(merged[source])
    settings = NodeSettings(**values)
    for name in ("map_frame", "odom_frame", "base_frame", "odom_topic", "control_topic", "observations_topic"):
        if not getattr(settings, name).strip():
            raise ParameterError(f"{name} must not be empty")
    if len({settings.map_frame, settings.odom_frame, settings.base_frame}) < 3:
        raise ParameterError(f"map_frame, odom_frame and base_frame must differ (got {settings.map_frame!r}, "
                             f"{settings.odom_frame!r}, {settings.base_frame!r})")
    _check_fleet(settings)
    return settings


_ROBOT_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


def _check_fleet(settings: NodeSettings) -> None:
    """robots: distinct relative ROS names; initial_poses: empty or 3 finite numbers per robot;
    local_robot: empty or one of robots."""
    robots, poses = settings.robots, settings.initial_poses
    for name in robots:
        if not isinstance(name, str) or not _ROBOT_NAME.match(name):
            raise ParameterError(f"robots: {name!r} is not a relative ROS name (letters, digits, _ and /, "
                                 "not starting with a digit)")
    if len(set(robots)) < len(robots):
        raise ParameterError(f"robots: a name appears twice in {list(robots)}")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in poses):
        raise ParameterError(f"initial_poses: expected numbers, got {list(poses)!r}")
    if poses and len(poses) != 3 * len(robots):
        raise ParameterError(f"initial_poses: expected 3 numbers (x, y, yaw) per robot, {3 * len(robots)} "
                             f"for robots {list(robots)}, got {len(poses)}")
    for k, value in enumerate(poses):
        limit = math.pi if k % 3 == 2 else 1e7
        _check_range(f"initial_poses[{k}]", value, -limit, limit)
    if settings.local_robot and settings.local_robot not in robots:
        raise ParameterError(f"local_robot: {settings.local_robot!r} is not one of robots {list(robots)}")
    if settings.local_robot and not settings.segments_topic:
        raise ParameterError("segments_topic must not be empty with local_robot (distributed fleet mode)")


def _core_config(merged: dict[str, Any], settings: NodeSettings) -> SlamConfig:
    """SlamConfig from the core parameters; its validate() applies the ranges of the field metadata."""
    sections = {f.name for f in fields(SlamConfig)}
    nested: dict[str, dict[str, Any]] = {}
    for name, value in merged.items():
        section, _, key = name.partition(".")
        if section not in sections:
            continue
        if name == "motion.model":
            value = resolve_motion_model(value, settings.motion_source, settings.control_angular)
        elif name == "filter.seed":
            value = None if int(value) < 0 else int(value)
        nested.setdefault(section, {})[key] = value
    try:
        return SlamConfig.from_dict(nested)
    except (ValueError, TypeError) as error:
        raise ParameterError(str(error)) from None


_TYPE_NAMES = {bool: "a boolean", int: "an integer", float: "a double", str: "a string", list: "an array"}


def check_types(values: dict[str, Any]) -> None:
    """Refuse what the node's declared types refuse (an integer is a double; 100.0 is not an
    integer, 1 not a boolean), so a parameter file means the same to node and runner."""
    by_name = {spec.name: spec for spec in all_specs()}
    for name, value in values.items():
        spec = by_name.get(name)
        if spec is None or spec.default is None or value is None:
            continue
        value = as_declared_type(spec, value)
        kind = type(spec.default) if not isinstance(spec.default, tuple) else list
        ok = isinstance(value, (list, tuple)) if kind is list else (
            type(value) is kind if kind in (bool, int) else isinstance(value, kind) and not isinstance(value, bool))
        if not ok:
            raise ParameterError(f"{name}: expected {_TYPE_NAMES.get(kind, kind.__name__)}, got {value!r}")


def build(values: dict[str, Any]) -> tuple[SlamConfig, NodeSettings]:
    """SlamConfig and NodeSettings from flat parameter values; ParameterError names the culprit
    (an unknown name too, with the nearest valid one; the names ROS itself reads are let through)."""
    check_names(values)
    check_types(values)
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
        if spec.choices and isinstance(spec.default, str):      # lists of names: by SlamConfig.validate
            _check_choice(spec.name, merged[spec.name], spec.choices)
    settings = _node_settings(merged)
    config = _core_config(merged, settings)
    if settings.robots and config.em.m_step != "observed":
        raise ParameterError("em.m_step must be observed with robots (fleet mode): the complete-data M-step "
                             "keeps statistics smoothed over one robot's particles")
    return config, settings
