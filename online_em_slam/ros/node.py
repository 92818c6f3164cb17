"""ROS 2 node: landmark SLAM by particle online EM.

Inputs
  ``odom`` (nav_msgs/Odometry), ``control`` (geometry_msgs/TwistStamped, with
  motion_source = control), ``landmark_observations`` (sensor_msgs/PointCloud2),
  ``/initialpose``; the fields each one needs are in :mod:`.inputs`.
Outputs
  ``~/pose`` ``~/path`` ``~/particles`` ``~/landmarks`` ``~/landmark_markers``,
  map -> odom (tf2_ros, else tf2_msgs/TFMessage on /tf, else ~/map_to_odom) and
  /diagnostics.  Without tf2_ros and tf2_msgs (PyPI wheels) ``main`` first builds
  tf2_msgs into the environment, once (:mod:`online_em_slam.messages.tf2_build`).
  Services ``~/reset`` ``~/pause`` ``~/save_map`` ``~/load_map`` (a file name per call)
  and ``~/save_map_file`` ``~/load_map_file`` (``map_file``).

The node holds the estimator, the settings and the shared state (lock, drop
counters, pause) and wires its parts, one module each:

  :mod:`.inputs`       subscriptions and the input pipeline shared with the offline
                       runner (:mod:`online_em_slam.pipeline`): stamp checks, loss
                       detection, the stamp-ordered merge (``input_delay``), load
                       shedding and the feeder, so the node and ``online-em-slam run``
                       feed the estimator the identical sequence;
  :mod:`.outputs`      publishers and map -> odom, called back by the pipeline for
                       every applied input;
  :mod:`.diagnostics`  /diagnostics;
  :mod:`.services`     reset, pause, initialpose;
  :mod:`.map_files`    save/load map by file name.

Every input that cannot be used is dropped and counted by reason (node counters
merged with the pipeline's and the core's, :meth:`OnlineEmSlamNode.all_drops`).
"""
from __future__ import annotations

import sys
import threading
from collections import Counter
from contextlib import contextmanager
from dataclasses import replace

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType, JumpThreshold
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, State, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.timer import Timer
from std_msgs.msg import Header

from ..core.filter.slam import OnlineEMSlam
from ..messages.tf2_build.first_use import ensure as ensure_tf2_msgs
from . import conversions as conv
from .diagnostics import Diagnostics
from .fleet_estimate import FleetEstimate
from .fleet_inputs import FleetInputs
from .fleet_names import initial_poses
from .inputs import Inputs
from .outputs import Outputs
from ..parameters.specs import (ParameterError, all_specs, as_declared_type, build, check_names, current_values,
                                declare_parameters)
from .qos import input_qos, latched_qos
from .map_files import MapFiles
from .services import Commands
from .segment_link import PERIOD as SEGMENT_PERIOD, SegmentLink
from .throttle import Throttle
from . import warmup_replay

__all__ = ["OnlineEmSlamNode", "input_qos", "latched_qos", "main"]


class OnlineEmSlamNode(LifecycleNode):
    """Particle online EM landmark SLAM as a ROS 2 managed (lifecycle) node (see module docstring).

    configure: the estimator, publishers, services, the input pipeline, the map file if
    ``load_map_on_start``; activate: the input subscriptions and the timers; deactivate:
    no more inputs, the estimate kept; cleanup: everything configure made.  With
    ``autostart`` (the default) the node configures and activates itself, so ``ros2 run``
    maps at once; without, a lifecycle manager (or ``ros2 lifecycle set``) drives it.
    """

    def __init__(self, node_name: str = "online_em_slam", **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self._declare_parameters()
        self._made: dict[str, list] = {"configure": [], "activate": []}
        self.segment_link = None
        self._jump_handle = None
        if self.settings.autostart:
            self.trigger_configure()
            self.trigger_activate()

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: State) -> TransitionCallbackReturn:
        with self._making("configure"):
            self._make_estimator()
            self._make_outputs()
            self._make_inputs()
            self._make_services()
        if self.settings.load_map_on_start:
            self.log_result(*self.map_files.load())
        s = self.settings
        self.get_logger().info(
            f"online EM SLAM: motion_source={s.motion_source} (model {self.config.motion.model}), "
            f"{self.config.filter.num_particles} particles, EM {self.config.em.algorithm}"
            + (f"; fleet of {len(s.robots)} robots: {', '.join(s.robots)}" if self.fleet_mode else "")
            + f"; map -> odom via {self.transform_kind}" + ("" if s.publish_tf else " (publish_tf is false)")
            + f"; sensor pose from {'TF, else ' if self.inputs.frames.uses_tf else ''}sensor.offset_*")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        with self._making("activate"):
            self.inputs.subscribe()
            self._make_timers()
            self._make_segment_link()
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self.inputs.unsubscribe()
        self._destroy("activate")
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._destroy("configure")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        if self._made["activate"]:
            self.inputs.unsubscribe()
        self._destroy("activate")
        self._destroy("configure")
        return TransitionCallbackReturn.SUCCESS

    @contextmanager
    def _making(self, transition: str):
        """Record the publishers, subscriptions, services and timers a transition creates."""
        before = {id(entity) for entity in self._entities()}
        yield
        self._made[transition] += [e for e in self._entities() if id(e) not in before]

    def _entities(self) -> list:
        return [*self.publishers, *self.subscriptions, *self.services, *self.timers]

    def _destroy(self, transition: str) -> None:
        """Destroy what ``transition`` created (those still there)."""
        if transition == "activate" and self._jump_handle is not None:
            self._jump_handle.unregister()
            self._jump_handle = None
        alive = {id(e) for e in self._entities()}
        for entity in self._made[transition]:
            if id(entity) in alive:
                self._destroy_entity(entity)
        self._made[transition] = []

    def _destroy_entity(self, entity) -> None:
        for kind, destroy in ((Publisher, self.destroy_publisher), (Subscription, self.destroy_subscription),
                              (Service, self.destroy_service), (Timer, self.destroy_timer)):
            if isinstance(entity, kind):
                destroy(entity)
                return

    # ------------------------------------------------------------------ set-up steps
    def _declare_parameters(self) -> None:
        """Declare the parameters and build the core configuration and node settings from them.

        The start-up overrides (parameter files, -p, parameter_overrides) are read as
        ``online-em-slam run`` reads a parameter file: a name that is neither the node's nor
        ROS's own is refused with the nearest valid name, and an integer is taken for a double.
        """
        self._check_overrides()
        declare_parameters(self)
        try:
            self.config, self.settings = build(current_values(self))
        except ParameterError as error:
            raise ParameterError(f"invalid parameter: {error}") from None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

    def _check_overrides(self) -> None:
        # rclpy keeps the overrides addressed to this node (its namespace and /**) here, and has
        # no public accessor for them; undeclared ones would otherwise be ignored silently.
        overrides = getattr(self, "_parameter_overrides", None)
        if isinstance(overrides, dict):
            check_names(overrides)        # ParameterError: unknown parameter: NAME (did you mean ...?)
            overrides.update({p.name: p for p in self._coerce_parameters(list(overrides.values()))})
        # ros2 param set ... 3 for a double, at run time: the same conversion.
        self.add_pre_set_parameters_callback(self._coerce_parameters)

    @staticmethod
    def _coerce_parameters(parameters: list[Parameter]) -> list[Parameter]:
        """An integer for a double parameter becomes a double (as online-em-slam run reads it)."""
        specs = {spec.name: spec for spec in all_specs()}
        out = []
        for parameter in parameters:
            spec = specs.get(parameter.name)
            value = parameter.value
            coerced = as_declared_type(spec, value) if spec is not None else value
            out.append(parameter if coerced is value else Parameter(parameter.name, value=coerced))
        return out

    def _make_estimator(self) -> None:
        """The estimator and the state the parts share (lock, drop counters, pause)."""
        self.lock = threading.RLock()
        self._slam = self._new_estimator()
        self._pending_config = None
        self.drops: Counter = Counter()             # node-level drops by reason
        self.throttle = Throttle(self.get_logger, lambda: self.settings.warn_throttle_period)
        self._core_drops_carry: Counter = Counter()  # drops of estimators replaced at a reset
        self.paused = False

    def _new_estimator(self):
        """OnlineEMSlam; with ``robots`` (fleet mode) the FleetSlam of every robot, one map."""
        s = self.settings
        if s.robots:
            estimator = FleetEstimate(self.config, initial_poses(s), s.robots, s.local_robot)
        else:
            estimator = OnlineEMSlam(self.config, initial_pose=s.initial_pose)
        estimator.replay_in_slices = True        # fed between the inputs (warmup_replay.py)
        return estimator

    @property
    def transform_kind(self) -> str:
        """Through which channel map -> odom goes (fleet mode: each robot's, alike)."""
        outputs = self.inputs.robots[0].outputs if self.fleet_mode else self.outputs
        return outputs.transform.kind

    @property
    def fleet_mode(self) -> bool:
        return isinstance(self._slam, FleetEstimate)

    def _make_outputs(self) -> None:
        """/diagnostics, then the publishers and map -> odom (they count updates into the diagnostics);
        in fleet mode only the map's (each robot's are made with its inputs)."""
        self.diagnostics = Diagnostics(self)
        self.outputs = Outputs(self, self.diagnostics, robot_outputs=not self.fleet_mode)

    def _make_inputs(self) -> None:
        """The input pipeline, which calls the outputs back (its subscriptions at activate); in fleet
        mode one per robot with the robot's outputs (fleet_inputs.py)."""
        if self.fleet_mode:
            self.inputs = FleetInputs(self, self.diagnostics)
        else:
            self.inputs = Inputs(self, self.outputs, self.diagnostics)

    def _make_services(self) -> None:
        """Services and /initialpose (``commands``: rclpy's Node already has a ``services`` property)."""
        self.commands = Commands(self)
        self.map_files = MapFiles(self)

    def _make_timers(self) -> None:
        """Housekeeping, map, diagnostics and map -> odom timers; the /clock jump callback."""
        s = self.settings
        # Timers run on the steady clock: they rate-limit work, independent of sim time.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._housekeeping_timer = self.create_timer(0.1, self.inputs.housekeeping, clock=self._steady)
        replay = warmup_replay.WarmupReplayFeeder(self)
        self._replay_timer = self.create_timer(warmup_replay.PERIOD, replay.tick, clock=self._steady)
        publish_map = self.inputs.publish_map if self.fleet_mode else self.outputs.publish_map
        self._map_timer = self.create_timer(s.map_publish_period, publish_map, clock=self._steady)
        self._diag_timer = self.create_timer(s.diagnostics_period, self.diagnostics.publish, clock=self._steady)
        self._tf_timer = None
        if s.transform_publish_period > 0:
            republish = self.inputs.republish_transform if self.fleet_mode else self.outputs.republish_transform
            self._tf_timer = self.create_timer(s.transform_publish_period, republish, clock=self._steady)
        # Reset on a backward jump of the ROS clock (bag played in a loop).
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(seconds=-s.time_jump_threshold),
                          on_clock_change=False),
            post_callback=self.inputs.on_clock_jump)

    def _make_segment_link(self) -> None:
        """Distributed fleet mode (``local_robot``): the segments out and in (segment_link.py)."""
        self.segment_link = None
        if self.settings.local_robot:
            self.segment_link = SegmentLink(self)
            self.create_timer(SEGMENT_PERIOD, self.segment_link.send, clock=self._steady)

    # ------------------------------------------------------------------ shared helpers
    def now_sec(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def header(self, stamp: float | None, frame: str) -> Header:
        """A header at ``stamp`` (the input stamp; now when None) in ``frame``."""
        return Header(stamp=conv.sec_to_stamp(stamp if stamp is not None else self.now_sec()), frame_id=frame)

    def log_result(self, ok: bool, message: str) -> None:
        if ok:
            self.get_logger().info(message)
        else:
            self.get_logger().error(message)

    def all_drops(self) -> dict[str, int]:
        """Node-level drop counters merged with the pipeline's and the core's, by reason."""
        with self.lock:
            merged = Counter(self.drops)
            merged.update(self.inputs.pipeline.drops)
            merged.update(self._core_drops_carry)
            merged.update(self._slam.drops)
            return {k: int(v) for k, v in merged.items() if v}

    @property
    def slam(self) -> OnlineEMSlam:
        return self._slam

    @property
    def inputs_received(self) -> int:
        """Well-formed inputs received (processed, queued or dropped after decoding)."""
        return self.diagnostics.inputs

    # ------------------------------------------------------------------ reset
    def reset(self, reason: str, keep_inputs: bool = False, keep_map: bool = False) -> None:
        """Restart the estimate; ``keep_inputs``: the input path already restarted on a confirmed jump;
        ``keep_map`` (a time jump, not asked by the user): only the pose and the time line restart."""
        with self.lock:
            s = self.settings
            if self.fleet_mode:
                self._reset_fleet(reason, keep_inputs, keep_map)
                return
            if keep_map:                 # as robot_localization and AMCL, the state survives a time jump
                self._slam.restart_time_line(s.initial_pose)
            elif self._pending_config is not None:
                self._core_drops_carry.update(self._slam.drops)
                self.config = self._pending_config
                self._pending_config = None
                self._slam = self._new_estimator()
            else:
                self._slam.reset(initial_pose=s.initial_pose, stamp=None)
            self.inputs.pipeline.restart(self._slam, keep_inputs=keep_inputs)
            self.outputs.reset()
            self.diagnostics.count_reset()
            self.get_logger().warning(f"estimate reset: {reason}" + ("; the map is kept" if keep_map else ""))

    def _reset_fleet(self, reason: str, keep_inputs: bool, keep_map: bool) -> None:
        """Fleet mode: a time jump restarts every robot's pose and time line; else a new fleet."""
        if keep_map:
            for io in self.inputs.robots:
                io.view.reset(reason, keep_inputs=keep_inputs, keep_map=True)
            return
        self._core_drops_carry.update(self._slam.drops)
        if self._pending_config is not None:
            self.config, self._pending_config = self._pending_config, None
        self._slam = self._new_estimator()
        self.inputs.restart(self._slam)
        self.outputs.reset()
        self.diagnostics.count_reset()
        self.get_logger().warning(f"estimate reset: {reason}")

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        values = current_values(self)
        values.update({p.name: p.value for p in parameters})
        try:
            build(values)
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, parameters) -> None:
        try:
            config, settings = build(current_values(self))
        except ParameterError as error:      # cannot happen: checked in _on_set_parameters
            self.get_logger().error(f"parameters not applied: {error}")
            return
        with self.lock:
            self.outputs.path.resize(settings.path_max_length, settings.path_publish_max_poses)
            if self.fleet_mode:
                config = replace(config, noise_learning=replace(config.noise_learning, replay_warmup=False))
            self.settings = settings
            self.inputs.apply_settings(settings)
            if config != self._slam.config:
                self._pending_config = config
                self.get_logger().info("core settings changed; they take effect at the next reset (~/reset)")
            else:
                self._pending_config = None


def main(args=None) -> int:
    try:
        rclpy.init(args=args)
    except Exception as error:        # noqa: BLE001  rcl refuses its arguments (a missing --params-file)
        reason = str(error).split(", at /")[0]      # rcl appends its source locations
        print(f"online_em_slam_node: error: {reason}", file=sys.stderr)
        return 1
    node = None
    code = 0
    try:
        logger = rclpy.logging.get_logger("online_em_slam")
        ensure_tf2_msgs(log=logger.info, warn=logger.warning)    # wheels-only environment: built once
        node = OnlineEmSlamNode()
        rclpy.spin(node)
    except ParameterError as error:     # one error line and status 1, as online-em-slam run
        rclpy.logging.get_logger("online_em_slam").error(str(error))
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    raise SystemExit(main())
