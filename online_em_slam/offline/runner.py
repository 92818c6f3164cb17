"""Offline runs: a bag straight into an estimator (no DDS), deterministic for a seed.

The bag is read with rosbags (no rclpy) and streamed, one message at a time,
through the node's own input pipeline (:mod:`online_em_slam.pipeline`: stamp checks,
the (stamp, tie rule) ordered merge of the streams within the node's ``input_delay``
window, the feeder), so the estimator sees the identical sequence of inputs as
the node and memory does not grow with the bag.  Observation clouds are read by the node's reader
(:func:`online_em_slam.messages.cloud.observations_from_message`) and odometry
orientations by the node's quaternion check (:mod:`online_em_slam.messages.quaternion`).
What the input path or the readers refuse is counted by reason
(``runner_skipped`` in metrics.json).  The command line is :mod:`online_em_slam.offline.cli`.
"""
from __future__ import annotations

import math
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import plots, report
from ..bag.bagio import absolute_topic
from ..messages.cloud import CloudFormatError, decode_message, observations_from_message
from ..core.config import SlamConfig
from .evaluation import DEFAULT_MATCH_GATE, InitialPose, initial_pose_from_gps
from .frames import check_frame, points_to_truth, poses_to_truth
from ..pipeline import CONTROL, KIND_NAME, OBSERVATIONS, ODOMETRY, InputPipeline
from ..bag.progress import Progress
from ..messages.quaternion import odometry_yaw
from .tum import write_revised_tum, write_run_tum

# Inputs that raised inside the estimator are dropped and counted (``internal_error``); the
# first few messages go into metrics.json's ``input_failures`` and the run's warning.
MAX_FAILURES_KEPT = 5


class FailureLog(list):
    """The first MAX_FAILURES_KEPT inputs that raised inside the estimator, as messages."""

    def note(self, item, fed) -> None:
        if fed.error is not None and len(self) < MAX_FAILURES_KEPT:
            self.append(f"{KIND_NAME[item.kind]} at {item.stamp:.3f}: {fed.error!r}")

METHODS = ("online_em", "ekf_slam", "fastslam2", "marginal_slam")
GT_POSITION_TOPIC = "/ground_truth/position"
GT_POSE_TOPIC = "/ground_truth/pose"          # full base pose (motion capture), where a data set has it
GT_LANDMARKS_TOPIC = "/ground_truth/landmarks"


# --------------------------------------------------------------------------- bag -> inputs

@dataclass
class BagInputs:
    """What a run needs from a bag: the inputs, streamed, and the compact references.

    ``events`` re-reads the bag at each iteration (one message held at a time, so
    a bag of any size streams; compare runs it once per method); odometry poses,
    GPS and the surveyed landmarks are read once, as arrays (tens of bytes a
    message), for the initial pose and the metrics.
    """

    path: str
    events: "BagEvents"                   # (kind, stamp, payload, log_time), kind as in online_em_slam.pipeline
    odom_times: np.ndarray
    odom_poses: np.ndarray
    gps_times: np.ndarray
    gps_xy: np.ndarray
    landmarks: np.ndarray | None          # (K, 2) surveyed landmarks
    landmark_ids: np.ndarray | None
    gt_pose_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gt_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))   # (n, 3) base x, y, yaw
    topics: dict = field(default_factory=dict)
    refused: Counter = field(default_factory=Counter)   # inputs the readers refused, by reason (set by feed)
    motion_source: str = "odom"           # which motion input drives the estimator (node setting)
    jump_threshold: float = 1.0           # node setting time_jump_threshold (stamp outliers)
    start: float | None = None            # stamp of the first input, in log-time order
    input_delay: float = 1.0              # node setting: the reorder window (s of log time), see feed

    @property
    def has_gps(self) -> bool:
        return len(self.gps_times) >= 2


class BagEvents:
    """The bag's motion and observation inputs in log-time order, read anew at each iteration.

    ``stream(refused)`` yields (kind, stamp, payload, log_time) and counts what the
    readers refuse in ``refused``; ``len`` is the number of messages on the input
    topics (so ``not events`` says there are none).  Odometry that does not drive the
    estimator (motion_source control) is not read again: the first pass counted its
    refusals (``odometry_refused``); reading Victoria Park's 62,000 odometry messages
    again took 2.2 s.
    """

    def __init__(self, bag, settings, count: int, namespace: str = "",
                 odometry_refused: Counter | None = None) -> None:
        self.bag, self.settings, self.count, self.namespace = bag, settings, int(count), namespace
        self.odometry_refused = Counter() if odometry_refused is None else odometry_refused

    def __len__(self) -> int:
        return self.count

    def __iter__(self):
        return self.stream(Counter())

    def stream(self, refused: Counter):
        from ..bag.bagio import read_bag_timed

        reader = BagReader(self.settings, keep_poses=False, namespace=self.namespace)
        reader.refused = reader.odometry_refused = refused
        if reader.motion_source != "odom":
            refused.update(self.odometry_refused)
        for topic, stamp, msg, log_time in read_bag_timed(self.bag, reader.event_topics):
            reader.handlers[topic](stamp, msg)
            while reader.events:
                kind, stamp, payload = reader.events.popleft()
                yield kind, stamp, payload, log_time


def namespaced(namespace: str, topic: str) -> str:
    """The bag topic of a node topic in ``namespace`` ("" or "/robot1"): "/robot1/odom"."""
    return absolute_topic(topic) if not namespace else namespace.rstrip("/") + absolute_topic(topic)


class BagReader:
    """A bag's messages to inputs, one handler per topic: motion and observation messages
    become events (kind, stamp, payload) queued in ``events`` until taken; odometry poses
    (``keep_poses``), GPS and the surveyed landmarks are collected.  ``namespace`` ("/robot1"):
    one robot's topics of a fleet bag, ground truth included; the survey is the fleet's."""

    def __init__(self, settings, keep_poses: bool = True, namespace: str = ""):
        self.motion_source = settings.motion_source
        self.keep_poses = keep_poses
        odom, observations = (namespaced(namespace, t) for t in (settings.odom_topic, settings.observations_topic))
        self.handlers = {observations: self.observations, odom: self.odometry,
                         namespaced(namespace, GT_POSITION_TOPIC): self.gps,
                         namespaced(namespace, GT_POSE_TOPIC): self.ground_truth_pose,
                         GT_LANDMARKS_TOPIC: self.surveyed_landmarks}
        self.event_topics = {observations}
        if settings.motion_source == "control":
            control = namespaced(namespace, settings.control_topic)
            self.handlers[control] = self.control
            self.event_topics.add(control)
        else:
            self.event_topics.add(odom)
        self.events: deque = deque()
        self.odom_t, self.odom_p, self.gps_t, self.gps_xy = [], [], [], []
        self.gt_t, self.gt_p = [], []
        self.landmarks = self.landmark_ids = None
        self.refused: Counter = Counter()
        self.odometry_refused: Counter = Counter()     # odometry refusals are counted in any mode
        self.counts: Counter = Counter()

    def odometry(self, stamp: float, msg) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        yaw, problem = odometry_yaw(q)
        if problem == "degenerate_quaternion":        # the node refuses these too
            self.odometry_refused[problem] += 1
            return
        pose = (float(p.x), float(p.y), yaw)
        if self.keep_poses:
            self.odom_t.append(stamp)
            self.odom_p.append(pose)
        if self.motion_source == "odom":
            self.events.append((ODOMETRY, stamp, pose))

    def control(self, stamp: float, msg) -> None:
        self.events.append((CONTROL, stamp, (float(msg.twist.linear.x), float(msg.twist.angular.z))))

    def observations(self, stamp: float, msg) -> None:
        try:
            self.events.append((OBSERVATIONS, stamp, observations_from_message(msg, drops=self.refused)))
        except CloudFormatError:
            self.refused["malformed_cloud"] += 1

    def gps(self, stamp: float, msg) -> None:
        self.gps_t.append(stamp)
        self.gps_xy.append((float(msg.point.x), float(msg.point.y)))

    def ground_truth_pose(self, stamp: float, msg) -> None:
        yaw, problem = odometry_yaw(msg.pose.orientation)
        if problem == "degenerate_quaternion":
            return
        self.gt_t.append(stamp)
        self.gt_p.append((float(msg.pose.position.x), float(msg.pose.position.y), yaw))

    def surveyed_landmarks(self, stamp: float, msg) -> None:
        if self.landmarks is not None:                # latched: the first copy is the survey
            return
        cols = decode_message(msg, required=("x", "y"))
        self.landmarks = np.stack([cols["x"], cols["y"]], axis=1).astype(float)
        self.landmark_ids = np.asarray(cols["id"], dtype=int) if "id" in cols else np.arange(len(self.landmarks))


def check_bag_topics(bag, settings, namespace: str = "") -> None:
    """Refuse (BagError, one line naming the bag) an empty bag, or one whose topics carry another
    message type than the node reads there, or two types."""
    from ..bag.bagio import BagError, bag_connections, node_topic_types, type_problems

    expected = node_topic_types(*(namespaced(namespace, t) for t in
                                  (settings.odom_topic, settings.control_topic, settings.observations_topic)))
    connections = bag_connections(bag)
    problems = type_problems([(topic, msgtype) for topic, msgtype, _ in connections], expected)
    if problems:
        raise BagError(f"{bag}: {'; '.join(problems)}")
    if not sum(count for _, _, count in connections):
        raise BagError(f"{bag}: the bag holds no messages")


def check_inputs_present(bag, settings, counts: Counter, namespace: str = "") -> None:
    """Refuse (BagError) a bag without motion input or without observations (``counts``: messages
    read per topic)."""
    from ..bag.bagio import BagError

    motion = namespaced(namespace, settings.control_topic if settings.motion_source == "control"
                        else settings.odom_topic)
    if not counts[motion]:
        raise BagError(f"{bag}: no motion input: no messages on {motion} (motion_source: {settings.motion_source})")
    observations = namespaced(namespace, settings.observations_topic)
    if not counts[observations]:
        raise BagError(f"{bag}: no observations: no messages on {observations}, nothing to map")


def read_inputs(bag, settings, namespace: str = "") -> BagInputs:
    """First pass over ``bag`` (settings: NodeSettings): odometry poses, GPS, surveyed landmarks,
    message counts and the first input's stamp; the inputs themselves stream from ``events``.
    ``namespace`` ("/robot1"): that robot's inputs of a fleet bag."""
    from ..bag.bagio import read_bag_timed

    check_bag_topics(bag, settings, namespace)
    reader = BagReader(settings, namespace=namespace)
    start = None

    def decode(topic: str) -> bool:          # input clouds and controls: only the first is decoded
        return start is None or topic not in reader.event_topics or topic == namespaced(namespace, settings.odom_topic)

    for topic, stamp, msg, _ in read_bag_timed(bag, set(reader.handlers), decode):
        reader.counts[topic] += 1
        if msg is not None:
            reader.handlers[topic](stamp, msg)
        if reader.events:
            start = reader.events[0][1] if start is None else start
            reader.events.clear()
    check_inputs_present(bag, settings, reader.counts, namespace)
    n_inputs = sum(reader.counts[t] for t in reader.event_topics)
    events = BagEvents(bag, settings, n_inputs if start is not None else 0, namespace, reader.odometry_refused)
    return BagInputs(str(bag), events,
                     np.asarray(reader.odom_t, dtype=float), np.asarray(reader.odom_p, dtype=float).reshape(-1, 3),
                     np.asarray(reader.gps_t, dtype=float), np.asarray(reader.gps_xy, dtype=float).reshape(-1, 2),
                     reader.landmarks, reader.landmark_ids,
                     np.asarray(reader.gt_t, dtype=float), np.asarray(reader.gt_p, dtype=float).reshape(-1, 3),
                     dict(reader.counts), Counter(), settings.motion_source,
                     settings.time_jump_threshold, start, settings.input_delay)


# --------------------------------------------------------------------------- initial pose

def parse_pose(text: str) -> tuple[float, float, float]:
    parts = [float(v) for v in text.split(",")]
    if len(parts) != 3 or not all(math.isfinite(v) for v in parts):
        raise ValueError(f"expected X,Y,YAW, got {text!r}")
    return parts[0], parts[1], parts[2]


def choose_initial_pose(mode: str, inputs: BagInputs, config: SlamConfig, settings, file_values: dict
                        ) -> InitialPose:
    """``--initial-pose`` (see :mod:`online_em_slam.offline.cli`): auto, params, ground_truth, gps or X,Y,YAW."""
    start = inputs.start if inputs.start is not None else 0.0
    sets_pose = any(k.startswith("initial_pose.") for k in file_values)
    if mode == "auto":
        mode = "params" if sets_pose else ("ground_truth" if len(inputs.gt_pose_times) else
                                           "gps" if inputs.has_gps else "params")
    if mode == "params":
        x, y, yaw = settings.initial_pose
        return InitialPose(x, y, yaw, start, "params file" if sets_pose else "default (0, 0, 0)")
    if mode == "ground_truth":
        return ground_truth_start(inputs, start)
    if mode == "gps":
        if not inputs.has_gps:
            raise ValueError(f"--initial-pose gps: the bag has no {GT_POSITION_TOPIC}")
        return gps_start(inputs, config, start)
    x, y, yaw = parse_pose(mode)
    return InitialPose(x, y, yaw, start, "command line")


def ground_truth_start(inputs: BagInputs, start: float) -> InitialPose:
    """The ground-truth pose at the first input (the last one at or before it; else the first),
    as the first GPS fix gives it for the KTH data."""
    if not len(inputs.gt_pose_times):
        raise ValueError(f"--initial-pose ground_truth: the bag has no {GT_POSE_TOPIC}")
    i = max(int(np.searchsorted(inputs.gt_pose_times, start + 1e-9)) - 1, 0)
    x, y, yaw = inputs.gt_poses[i]
    return InitialPose(float(x), float(y), float(yaw), start, f"{GT_POSE_TOPIC} at {inputs.gt_pose_times[i]:.3f}",
                       in_truth_frame=True)


def truth_start(inputs: BagInputs, config: SlamConfig) -> InitialPose | None:
    """Where the ground truth puts the robot at the first input: its pose topic, else the
    GPS-derived pose (as ``--initial-pose gps``); None when the bag has neither (or the GPS
    track cannot give a heading)."""
    start = inputs.start if inputs.start is not None else 0.0
    if len(inputs.gt_pose_times):
        return ground_truth_start(inputs, start)
    if not inputs.has_gps:
        return None
    try:
        return gps_start(inputs, config, start)
    except ValueError:
        return None


def gps_start(inputs: BagInputs, config: SlamConfig, start: float) -> InitialPose:
    """The base pose at ``start`` from the GPS track (and the odometry's shape, when the bag has it)."""
    odom = (inputs.odom_times, inputs.odom_poses) if len(inputs.odom_times) >= 2 else (None, None)
    return initial_pose_from_gps(inputs.gps_times, inputs.gps_xy, (config.sensor.offset_x, config.sensor.offset_y),
                                 start, odom[0], odom[1])


# --------------------------------------------------------------------------- running

def make_estimator(method: str, config: SlamConfig, initial_pose):
    if method == "online_em":
        from ..core import OnlineEMSlam
        return OnlineEMSlam(config, initial_pose=initial_pose)
    if method == "ekf_slam":
        from ..baselines import EkfSlam
        return EkfSlam(config, initial_pose=initial_pose)
    if method == "fastslam2":
        from ..baselines import FastSlam2
        return FastSlam2(config, initial_pose=initial_pose)
    if method == "marginal_slam":
        from ..baselines import MarginalSlam
        return MarginalSlam(config, initial_pose=initial_pose)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


@dataclass
class RunResult:
    method: str
    trajectory: np.ndarray                # (n, 4): t, x, y, yaw
    landmarks: object                     # LandmarkMap
    durations: list
    wall_time: float
    dataset_duration: float
    drops: dict
    skipped: dict
    n_observation_messages: int
    known_ids: bool = False               # some observation carried a landmark id (known association)
    failures: list = field(default_factory=list)   # the first inputs that raised inside the estimator
    revised: np.ndarray | None = None     # (n, 4): the trajectory as the last replay filtered it again


def revised_trajectory(replayed: np.ndarray | None, published: np.ndarray) -> np.ndarray | None:
    """(n, 4) t, x, y, yaw: the poses of the last replay (OnlineEMSlam.revised_trajectory), then
    ``published`` after its take-over; None without a replay."""
    if replayed is None or not len(replayed):
        return None
    return np.vstack([replayed, published[published[:, 0] > replayed[-1, 0]]])


def feed(estimator, inputs: BagInputs) -> RunResult:
    """Stream the bag's inputs through the node's input pipeline; record the pose after every observation message.

    The bag's log time stands for the node's wall clock (it is when the inputs
    arrived): the merge waits for a stream only while it delivers within
    ``input_delay`` of log time, the node's rule, so the inputs held for
    reordering are bounded by that window (and by how far a live stream's stamps
    lag), not by the bag.  An input that arrives after its place in the order
    was released is counted (``out_of_order``, as in the node); the end of the
    bag releases the rest.  ``wall_time`` is the time spent in the pipeline and
    the estimator (reading the bag excluded).
    """
    durations, rows, refused, failures = [], [], Counter(), FailureLog()

    def record(item, fed) -> None:
        failures.note(item, fed)
        if fed.report is not None:
            durations.append(fed.report.duration)
        if fed.trajectory_point is not None:
            rows.append(fed.trajectory_point)

    pipeline = InputPipeline(estimator, inputs.motion_source, inputs.input_delay, inputs.jump_threshold,
                             restart_on_jump_back=False, on_applied=record)
    first = last = None
    n_obs_msgs, busy, known_ids = 0, 0.0, False
    bar = Progress(len(inputs.events), "run", enabled=sys.stderr.isatty())   # a terminal only, not logs
    for kind, stamp, payload, log_time in inputs.events.stream(refused):
        bar.update()
        first = stamp if first is None or stamp < first else first
        last = stamp if last is None or stamp > last else last
        n_obs_msgs += kind == OBSERVATIONS
        known_ids = known_ids or (kind == OBSERVATIONS and bool(np.any(payload.ids >= 0)))
        started = time.perf_counter()
        pipeline.push(kind, stamp, payload, log_time)
        busy += time.perf_counter() - started
    bar.close()
    started = time.perf_counter()
    pipeline.flush()
    busy += time.perf_counter() - started
    inputs.refused = refused
    skipped = {k: int(v) for k, v in pipeline.drops.items() if v}
    skipped.update({k: int(v) for k, v in refused.items() if v})
    trajectory = np.asarray(rows, dtype=float).reshape(-1, 4)
    return RunResult("", trajectory, estimator.landmarks(), durations, busy,
                     (last - first) if first is not None else 0.0, dict(estimator.drops), skipped, n_obs_msgs,
                     known_ids, failures,
                     revised_trajectory(getattr(estimator, "revised_trajectory", lambda: None)(), trajectory))


def run_one(inputs: BagInputs, config: SlamConfig, method: str, initial: InitialPose, output: Path,
            plot: bool = True, match_gate: float = DEFAULT_MATCH_GATE, align: bool = False,
            extra: dict | None = None, param_values: dict | None = None, result: RunResult | None = None) -> dict:
    """Run ``method`` on the inputs; write DIR/trajectory.csv, landmarks.csv, metrics.json [, noise.yaml, map.png].

    ``param_values``: the parameter file's values, the base of noise.yaml.  ``result``: a run made
    otherwise (the batch, offline/batch_run.py), scored and written as a run of ``method``.
    """
    output.mkdir(parents=True, exist_ok=True)
    estimator = None
    if result is None:
        estimator = make_estimator(method, config, initial.pose)
        result = feed(estimator, inputs)
    result.method = method
    metrics = {"method": method, "bag": inputs.path, **(extra or {}),
               "seed": config.filter.seed, "num_particles": config.filter.num_particles,
               "motion_model": config.motion.model, "initial_pose": initial.to_dict()}
    frame = check_frame(initial, truth_start(inputs, config), match_gate)
    metrics.update(report.evaluate(result, inputs, config, match_gate, align, frame))
    offset = (config.sensor.offset_x, config.sensor.offset_y)
    report.write_trajectory(output / "trajectory.csv", result.trajectory)
    write_run_tum(output, result.trajectory, offset, inputs.gps_times, inputs.gps_xy)   # TUM files for evo
    write_revised_tum(output, result.revised)
    report.write_landmarks(output / "landmarks.csv", result.landmarks)
    if hasattr(estimator, "learned_noise"):                  # online EM: the noise it ended with
        metrics["noise_learned"] = estimator.learned_noise()
        report.write_noise_params(output / "noise.yaml", estimator.learned_noise_parameters(), param_values or {},
                                  metrics["noise_learned"])
    report.json_dump(output / "metrics.json", metrics)
    if plot:
        lm = result.landmarks           # drawn where they were scored: in the ground-truth frame
        trajectory = np.column_stack([result.trajectory[:, 0], poses_to_truth(frame, result.trajectory[:, 1:4])])
        plots.plot_map(output / "map.png", f"{method}: {Path(inputs.path).name}", trajectory,
                       points_to_truth(frame, lm.positions), lm.ids,
                       np.asarray(lm.n_obs) >= config.association.confirm_observations,
                       inputs.landmarks, inputs.gps_xy, offset)
    return metrics
