"""Convert one robot of the UTIAS MRCLAM dataset to a ROS 2 bag (rosbags, Jazzy typestore); no rclpy needed.

Command line (through the KTH converter's entry point)::

    online-em-slam-convert mrclam OUTPUT --data-dir DIR_OR_ARCHIVE --robot K [--seconds S] [--start S0]
                           [--unknown-ids] [--storage mcap|sqlite3] [--overwrite] [--no-progress]

Two layers, as in :mod:`online_em_slam.datasets.kth.convert` (whose message helpers are reused):
:func:`mrclam_streams` (pure numpy: the arrays the bag holds) and
:func:`write_mrclam_bag` (rosbags messages in time order, mcap or sqlite3).

Stamps: every header stamp and log time is the dataset time + ``STAMP_OFFSET``
(1e9 s, 2001-09-09).  The dataset clock starts at 0 (odometry, ground truth), and
ROS treats a zero stamp as "unset", so a fixed epoch is added that keeps every
stamp positive; subtract it to get back the dataset's seconds.

==========================  ==============================  ===========  ==========================================
topic                       type                            frame        content
==========================  ==============================  ===========  ==========================================
/tf_static                  tf2_msgs/msg/TFMessage          base_link    base_link -> camera (identity), latched
/ground_truth/landmarks     sensor_msgs/msg/PointCloud2     map          landmarks x, y, z = 0, id = subject, latched
/control                    geometry_msgs/msg/TwistStamped  base_link    linear.x = v, angular.z = w, 50 Hz
/odom                       nav_msgs/msg/Odometry           odom         integrated commands, twist (v, w), 50 Hz
/tf                         tf2_msgs/msg/TFMessage          odom         odom -> base_link (= /odom pose)
/ground_truth/position      geometry_msgs/msg/PointStamped  map          Vicon x, y, 10 Hz (every 5th sample)
/ground_truth/pose          geometry_msgs/msg/PoseStamped   map          Vicon x, y, yaw, 10 Hz
/landmark_observations      sensor_msgs/msg/PointCloud2     camera       one cloud per measurement time
==========================  ==============================  ===========  ==========================================

/odom: the velocity commands integrated from (0, 0, 0) at the first odometry sample,
command k held over [t_k, t_k+1] along the exact arc of constant (v, w) (not Euler).
Covariances are 0 (not estimated).  The observation clouds have the fields of
:data:`online_em_slam.messages.cloud.OBSERVATION_FIELDS`: x, y, z (sensor frame, z = 0), range,
bearing (0 = forward, counter-clockwise positive), id = landmark subject number (6-20;
-1 for all with ``unknown_ids``), range_std = bearing_std = 0 ("use the configured
noise").  All barcodes read at one time are one image, one cloud; times without a kept
measurement have no cloud.  The ground truth is in the Vicon frame, called ``map``:
a node started at the first ground-truth pose has its map there.  Messages sharing a
stamp are ordered static first, motion before observations (``TOPIC_PRIORITY``).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...messages.cloud import OBSERVATION_FIELDS
from ..kth.beacons import observation_columns
from ...bag.bagio import clear_bag_directory, jazzy_typestore, message_order, write_topics
from ..kth.convert import MSGTYPES as KTH_MSGTYPES
from ..kth.convert import (FRAME_BASE, FRAME_MAP, GROUND_TRUTH_LANDMARK_FIELDS, TOPIC_CONTROL, TOPIC_GT_LANDMARKS,
                           TOPIC_GT_POSITION, TOPIC_ODOM, TOPIC_OBSERVATIONS, TOPIC_TF, TOPIC_TF_STATIC, DeadReckoning,
                           MessageFactory, Observations, dir_size, to_ns)
from .dataset import DROP_REASONS, MrclamRun, load_mrclam

#: Added to every dataset time (seconds) to make the stamps: no stamp is zero or negative.
STAMP_OFFSET = 1_000_000_000.0
_STAMP_OFFSET_NS = 1_000_000_000 * 1_000_000_000
#: Every n-th ground-truth sample (50 Hz -> 10 Hz).
GROUND_TRUTH_EVERY = 5

TOPIC_GT_POSE = "/ground_truth/pose"
# The KTH bags' topics and order (no /scan), with the full ground-truth pose after the position.
_TOPICS = (TOPIC_TF_STATIC, TOPIC_GT_LANDMARKS, TOPIC_CONTROL, TOPIC_ODOM, TOPIC_TF, TOPIC_GT_POSITION)
MSGTYPES = {**{t: KTH_MSGTYPES[t] for t in _TOPICS}, TOPIC_GT_POSE: "geometry_msgs/msg/PoseStamped",
            TOPIC_OBSERVATIONS: KTH_MSGTYPES[TOPIC_OBSERVATIONS]}
#: Order of messages sharing one stamp (static data first, motion before sensing).
TOPIC_PRIORITY = {t: i for i, t in enumerate(MSGTYPES)}
LATCHED_TOPICS = (TOPIC_TF_STATIC, TOPIC_GT_LANDMARKS)
FRAME_CAMERA = "camera"


# --------------------------------------------------------------------------- pure layer

@dataclass(frozen=True)
class LabelledObservations(Observations):
    """Observations grouped per image (CSR, as the KTH ones) with a landmark id per detection."""

    ids: np.ndarray | None = None


@dataclass(frozen=True)
class MrclamStreams:
    """Everything the bag holds, as arrays on the dataset clock (no STAMP_OFFSET).

    ``odom`` carries the commands too: speed = v, yaw_rate = w (/control and the /odom twist).
    """

    name: str
    odom: DeadReckoning
    observations: LabelledObservations
    ground_truth_times: np.ndarray
    ground_truth_poses: np.ndarray
    landmark_subjects: np.ndarray
    landmark_xy: np.ndarray

    @property
    def start_time(self) -> float:
        firsts = [self.odom.times[:1], self.observations.times[:1], self.ground_truth_times[:1]]
        return float(np.min(np.concatenate(firsts)))

    def per_topic_times(self) -> dict[str, np.ndarray]:
        """Dataset time of every message, per topic (latched ones once, at the start)."""
        t0 = np.array([self.start_time])
        return {TOPIC_TF_STATIC: t0, TOPIC_GT_LANDMARKS: t0, TOPIC_CONTROL: self.odom.times,
                TOPIC_ODOM: self.odom.times, TOPIC_TF: self.odom.times, TOPIC_GT_POSITION: self.ground_truth_times,
                TOPIC_GT_POSE: self.ground_truth_times, TOPIC_OBSERVATIONS: self.observations.times}

    def message_counts(self) -> dict[str, int]:
        return {topic: len(times) for topic, times in self.per_topic_times().items()}


def integrate_velocities(times, v, w, initial_pose=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Poses (n, 3) at ``times`` from commands (v, w), command k held over [t_k, t_k+1].

    Exact arcs of constant (v, w): heading += w dt; the position moves by the chord
    v dt sinc(w dt / 2) along the mid-heading (a straight line when w = 0).
    """
    t, v, w = (np.asarray(a, dtype=np.float64) for a in (times, v, w))
    dt = np.diff(t)
    turn = w[:-1] * dt
    heading = initial_pose[2] + np.concatenate([[0.0], np.cumsum(turn)])
    chord = v[:-1] * dt * np.sinc(turn / (2.0 * np.pi))          # np.sinc(x) = sin(pi x) / (pi x)
    mid = heading[:-1] + 0.5 * turn
    poses = np.empty((len(t), 3))
    poses[:, 0] = initial_pose[0] + np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
    poses[:, 1] = initial_pose[1] + np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
    poses[:, 2] = np.arctan2(np.sin(heading), np.cos(heading))
    return poses


def group_observations(times, ranges, bearings, ids) -> LabelledObservations:
    """One group per distinct time (``times`` sorted): all barcodes read at one time are one image."""
    times = np.asarray(times, dtype=np.float64)
    distinct, starts = np.unique(times, return_index=True)
    offsets = np.append(starts, len(times)).astype(np.int64)
    return LabelledObservations(distinct, offsets, np.asarray(ranges, dtype=np.float64),
                                np.asarray(bearings, dtype=np.float64), ids=np.asarray(ids, dtype=np.int32))


def mrclam_streams(run: MrclamRun, unknown_ids: bool = False,
                   ground_truth_every: int = GROUND_TRUTH_EVERY) -> MrclamStreams:
    """The bag's arrays for a loaded run; ``unknown_ids``: every observation id -1 (data association left
    to the estimator); ground truth decimated to every ``ground_truth_every``-th sample."""
    poses = integrate_velocities(run.odometry_times, run.odometry_v, run.odometry_w)
    odom = DeadReckoning(run.odometry_times, poses, run.odometry_v, run.odometry_w)
    ids = np.full(run.n_measurements, -1) if unknown_ids else run.measurement_subjects
    obs = group_observations(run.measurement_times, run.measurement_range, run.measurement_bearing, ids)
    step = slice(None, None, int(ground_truth_every))
    return MrclamStreams(f"mrclam_robot{run.robot}", odom, obs, run.ground_truth_times[step],
                         run.ground_truth_poses[step], run.landmark_subjects, run.landmark_xy)


def to_stamp_ns(t) -> np.ndarray:
    """Dataset seconds -> bag stamps in integer nanoseconds (STAMP_OFFSET added exactly)."""
    return to_ns(t) + _STAMP_OFFSET_NS


def message_schedule(streams: MrclamStreams) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Time order of all messages: (stamps_ns with the offset, topics, index within topic),
    sorted by stamp, then TOPIC_PRIORITY, then index."""
    return message_order({t: to_stamp_ns(times) for t, times in streams.per_topic_times().items()}, TOPIC_PRIORITY)


# --------------------------------------------------------------------------- rosbags messages

class MrclamMessageFactory(MessageFactory):
    """rosbags messages of the MRCLAM streams; /odom and /tf come from the KTH factory unchanged."""

    def __init__(self, streams: MrclamStreams, typestore=None):
        super().__init__(streams, typestore, map_to_gps=None)

    def tf_static(self, stamp_ns: int):
        return self.T["tf2_msgs/msg/TFMessage"](
            transforms=[self._transform(stamp_ns, FRAME_BASE, FRAME_CAMERA, 0.0, 0.0, 0.0)])

    def gt_landmarks(self, stamp_ns: int):
        s = self.s
        cols = {"x": s.landmark_xy[:, 0], "y": s.landmark_xy[:, 1], "z": np.zeros(len(s.landmark_xy)),
                "id": s.landmark_subjects.astype(np.int32)}
        return self._cloud(stamp_ns, FRAME_MAP, cols, GROUND_TRUTH_LANDMARK_FIELDS)

    def control(self, stamp_ns: int, i: int):
        return self.twist(stamp_ns, self.s.odom.speed[i], self.s.odom.yaw_rate[i])

    def gt_position(self, stamp_ns: int, i: int):
        x, y, _ = self.s.ground_truth_poses[i]
        return self.T["geometry_msgs/msg/PointStamped"](
            header=self.header(stamp_ns, FRAME_MAP), point=self.Point(x=float(x), y=float(y), z=0.0))

    def gt_pose(self, stamp_ns: int, i: int):
        x, y, yaw = (float(v) for v in self.s.ground_truth_poses[i])
        return self.T["geometry_msgs/msg/PoseStamped"](
            header=self.header(stamp_ns, FRAME_MAP),
            pose=self.T["geometry_msgs/msg/Pose"](position=self.Point(x=x, y=y, z=0.0), orientation=self._quat(yaw)))

    def observations(self, stamp_ns: int, i: int):
        obs = self.s.observations
        _, rng, brg = obs.scan(i)
        ids = obs.ids[int(obs.offsets[i]):int(obs.offsets[i + 1])]
        return self._cloud(stamp_ns, FRAME_CAMERA, observation_columns(rng, brg, ids), OBSERVATION_FIELDS)

    def build(self, topic: str, stamp_ns: int, i: int):
        if topic == TOPIC_TF_STATIC:
            return self.tf_static(stamp_ns)
        if topic == TOPIC_GT_LANDMARKS:
            return self.gt_landmarks(stamp_ns)
        return {TOPIC_CONTROL: self.control, TOPIC_ODOM: self.odom, TOPIC_TF: self.tf,
                TOPIC_GT_POSITION: self.gt_position, TOPIC_GT_POSE: self.gt_pose,
                TOPIC_OBSERVATIONS: self.observations}[topic](stamp_ns, i)


def iter_messages(streams: MrclamStreams, typestore=None):
    """Yield (stamp_ns, topic, msgtype, rosbags message) in time order."""
    factory = MrclamMessageFactory(streams, typestore)
    stamps, topics, index = message_schedule(streams)
    for stamp, topic, i in zip(stamps.tolist(), topics, index.tolist()):
        yield stamp, topic, MSGTYPES[topic], factory.build(topic, stamp, i)


def write_streams(streams: MrclamStreams, output, storage: str = "mcap", overwrite: bool = False,
                  progress: bool = True, stream=None) -> dict[str, int]:
    """Write the streams to a ROS 2 bag directory ``output``; returns messages per topic."""
    output = Path(output)
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"storage must be mcap or sqlite3, got {storage!r}")
    clear_bag_directory(output, overwrite)
    ts = jazzy_typestore()
    return write_topics(output, iter_messages(streams, ts), streams.message_counts(), MSGTYPES, LATCHED_TOPICS,
                        ts, storage, f"{streams.name} -> {output.name}", progress, stream)


def write_mrclam_bag(run: MrclamRun, output, storage: str = "mcap", overwrite: bool = False,
                     unknown_ids: bool = False, progress: bool = True) -> dict[str, int]:
    """Write a loaded run (:func:`~online_em_slam.datasets.mrclam.dataset.load_mrclam`) to the bag directory
    ``output``; returns messages per topic."""
    return write_streams(mrclam_streams(run, unknown_ids), output, storage, overwrite, progress)


# --------------------------------------------------------------------------- command line

def report_lines(run: MrclamRun) -> list[str]:
    """What the loader left out or changed, for the command line."""
    lines = ["dropped measurements: " + ", ".join(f"{r} {run.drops[r]}" for r in DROP_REASONS)
             + f" (kept {run.n_measurements})"]
    if run.start:
        kept = "the run" if run.seconds is None else f"{run.seconds:g} s"
        lines.append(f"{kept} from {run.start:g} s after the first odometry sample kept; rows cut: "
                     + ", ".join(f"{k} {v}" for k, v in run.truncated.items()))
    elif run.seconds is not None:
        lines.append(f"first {run.seconds:g} s kept; rows cut: "
                     + ", ".join(f"{k} {v}" for k, v in run.truncated.items()))
    elif any(run.truncated.values()):
        lines.append("rows outside the odometry span: " + ", ".join(f"{k} {v}" for k, v in run.truncated.items()))
    if any(run.retimed.values()):
        lines.append("times rebuilt on the 50 Hz grid (file rounds them to 5 significant digits): "
                     + ", ".join(f"{k} {v}" for k, v in run.retimed.items()))
    if run.survey_relabelled:
        lines.append("survey labels corrected (the measurements placed from the ground truth sit on the other "
                     "entry): " + ", ".join(f"subject {s} was listed as {e}" for s, e in
                                            sorted(run.survey_relabelled.items())))
    return lines


def fail(message: str) -> int:
    """One error line of ``online-em-slam-convert``; exit status 1."""
    print(f"online-em-slam-convert: error: {message}", file=sys.stderr)
    return 1


def convert_cli(args, convert, width: int = 28) -> int:
    """The MRCLAM conversions' command line after their own checks: ``convert()`` loads and writes,
    returning (messages per topic, report lines); prints them and the total; 0 or 1 (one error line)."""
    if args.data_dir is None:
        return fail("mrclam needs --data-dir (the MRCLAM_DatasetN directory or its .zip or .tar.xz)")
    if args.no_map_to_gps:
        return fail("--no-map-to-gps is for the KTH datasets (an MRCLAM bag has no map -> gps transform)")
    t0 = time.monotonic()
    try:
        counts, lines = convert()
    except (FileNotFoundError, FileExistsError, ValueError) as exc:
        return fail(str(exc))
    elapsed = time.monotonic() - t0
    for topic, n in counts.items():
        print(f"{topic:{width}s} {n:8d}")
    for line in lines:
        print(line)
    print(f"wrote {sum(counts.values())} messages to {args.output} "
          f"({dir_size(Path(args.output)) / 1e6:.1f} MB, {args.storage}) in {elapsed:.1f} s")
    return 0


def run_cli(args) -> int:
    """``online-em-slam-convert mrclam ...`` (arguments parsed by datasets.convert.main); 0 or 1 (one error line)."""
    if args.robot is None:
        return fail("mrclam needs --robot K (1-5) or --all-robots")

    def convert():
        run = load_mrclam(args.data_dir, args.robot, args.seconds, args.start)
        counts = write_mrclam_bag(run, args.output, args.storage, args.overwrite, args.unknown_ids,
                                  progress=not args.no_progress)
        return counts, report_lines(run)

    return convert_cli(args, convert)
