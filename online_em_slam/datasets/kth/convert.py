"""Convert the KTH datasets to ROS 2 bags (rosbags, Jazzy typestore); no rclpy needed.

Command line::

    online-em-slam-convert {car_park,victoria_park} OUTPUT [--data-dir D]
                           [--storage mcap|sqlite3] [--overwrite] [--no-progress]
                           [--no-map-to-gps]
    online-em-slam-convert mrclam OUTPUT --data-dir D --robot K ...   (online_em_slam.datasets.mrclam.convert)

Two layers:

* :func:`build_streams` (pure numpy): the time series that go into the bag
  (:class:`Streams`), so tests and the offline runner get exactly the same data
  without writing or reading a bag;
* :func:`iter_messages` / :func:`write_bag`: rosbags messages in time order, written
  to an mcap or sqlite3 bag.

Topics (all stamps are dataset times in seconds):

==========================  ==============================  ===========  =====================
topic                       type                            frame        content
==========================  ==============================  ===========  =====================
/tf_static                  tf2_msgs/msg/TFMessage          base_link    base_link -> laser (3.78, 0.5, 0)
                                                            map          map -> gps (see below)
/odom                       nav_msgs/msg/Odometry           odom         dead-reckoned base_link pose + twist
/tf                         tf2_msgs/msg/TFMessage          odom         odom -> base_link (= /odom pose)
/control                    geometry_msgs/msg/TwistStamped  base_link    linear.x = v_e, angular.z = alpha
/scan                       sensor_msgs/msg/LaserScan       laser        Car Park only, with intensities
/landmark_observations      sensor_msgs/msg/PointCloud2     laser        range/bearing, id = -1
/ground_truth/position      geometry_msgs/msg/PointStamped  gps          GPS fix (= laser point)
/ground_truth/landmarks     sensor_msgs/msg/PointCloud2     gps          Car Park beacons x, y, z, id
==========================  ==============================  ===========  =====================

Dead reckoning (/odom): the ACFR model of the rear-axle centre, Euler-integrated
with the control of sample k held over [t_k, t_k+1] (as core.models.motion.acfr):
v_c = v_e / (1 - tan(alpha) H / L), phi' = v_c tan(alpha) / L, starting at the
odom origin (0, 0, 0) at the first control sample.  Twist: linear.x = v_c,
angular.z = phi'.  Covariances are left at 0 (not estimated).

Observations: Car Park from :func:`extract_beacons` on every scan (an empty cloud
for scans without a beacon, so that the consumer sees every scan); Victoria Park
from tree_detections.dat (only scans with detections exist), with the range to
the trunk centre = file range + diameter / 2 (the file gives the range to the
trunk surface; the usual Victoria Park practice).  Bearings are in the sensor
frame (0 = forward, CCW positive).  range_std = bearing_std = 0 ("use the
configured noise").

/scan: ranges as float32, "no return" (>= 81.9 m) written as +inf (REP 117),
angle_min = -pi/2, angle_increment = 0.5 deg, range_max = 81.9, raw intensities.
TF tree: ``map -> odom`` comes from the SLAM node; the bag holds ``odom -> base_link``
on /tf (the odometry source owns it, REP-105) and the static ``base_link -> laser``
and ``map -> gps`` on /tf_static (latched).  The /ground_truth/* frame ``gps`` is the
GPS east/north frame.  ``map -> gps`` places it for a node started at
``initial_pose`` (0, 0, 0), the parameter files' default (map = the vehicle's
start frame): the inverse of the start pose fitted to the first GPS metres
(:func:`online_em_slam.offline.evaluation.initial_pose_from_gps`, as ``online-em-slam
run`` does), so the ground truth overlays the map in RViz.  A node started at
the GPS-derived pose has map = gps: convert with ``--no-map-to-gps`` for it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...bag.bagio import clear_bag_directory, jazzy_typestore, message_order, write_topics
from ...messages.cloud import OBSERVATION_FIELDS, build_message
from ...core.models import motion
from ...core.config import MotionConfig
from ...messages.quaternion import yaw_to_xyzw
from .beacons import extract_beacons, observation_columns
from .datasets import (VEHICLE, CarPark, GpsTrack, LaserScans, OdometryStream, Vehicle,
                       VictoriaPark, load_car_park, load_victoria_park)

GROUND_TRUTH_LANDMARK_FIELDS = (("x", "f4"), ("y", "f4"), ("z", "f4"), ("id", "i4"))

TOPIC_TF_STATIC = "/tf_static"
TOPIC_TF = "/tf"
TOPIC_ODOM = "/odom"
TOPIC_CONTROL = "/control"
TOPIC_SCAN = "/scan"
TOPIC_OBSERVATIONS = "/landmark_observations"
TOPIC_GT_POSITION = "/ground_truth/position"
TOPIC_GT_LANDMARKS = "/ground_truth/landmarks"

MSGTYPES = {
    TOPIC_TF_STATIC: "tf2_msgs/msg/TFMessage",
    TOPIC_GT_LANDMARKS: "sensor_msgs/msg/PointCloud2",
    TOPIC_CONTROL: "geometry_msgs/msg/TwistStamped",
    TOPIC_ODOM: "nav_msgs/msg/Odometry",
    TOPIC_TF: "tf2_msgs/msg/TFMessage",
    TOPIC_GT_POSITION: "geometry_msgs/msg/PointStamped",
    TOPIC_SCAN: "sensor_msgs/msg/LaserScan",
    TOPIC_OBSERVATIONS: "sensor_msgs/msg/PointCloud2",
}
#: Order of messages sharing one stamp (static data first, motion before sensing).
TOPIC_PRIORITY = {t: i for i, t in enumerate(MSGTYPES)}
#: Topics published latched (TRANSIENT_LOCAL) in the bag's offered QoS.
LATCHED_TOPICS = (TOPIC_TF_STATIC, TOPIC_GT_LANDMARKS)

FRAME_MAP, FRAME_ODOM, FRAME_BASE, FRAME_LASER = "map", "odom", "base_link", "laser"
#: Ground truth is in the GPS east/north frame, not the SLAM map frame (see the docstring).
FRAME_GPS = "gps"


# --------------------------------------------------------------------------- pure layer

@dataclass(frozen=True)
class Observations:
    """Landmark observations grouped per scan (CSR): scan i is offsets[i]:offsets[i+1]."""

    times: np.ndarray
    offsets: np.ndarray
    range: np.ndarray
    bearing: np.ndarray

    def __len__(self) -> int:
        return len(self.times)

    @property
    def n_detections(self) -> int:
        return len(self.range)

    def scan(self, i: int) -> tuple[float, np.ndarray, np.ndarray]:
        s = slice(int(self.offsets[i]), int(self.offsets[i + 1]))
        return float(self.times[i]), self.range[s], self.bearing[s]

    def __iter__(self):
        for i in range(len(self)):
            yield self.scan(i)


@dataclass(frozen=True)
class DeadReckoning:
    """base_link poses (n, 3) in ``odom`` and the twist (v_c, phi') at each control time."""

    times: np.ndarray
    poses: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray


@dataclass(frozen=True)
class Streams:
    """Everything the bag holds, as arrays (see the module docstring for the topics)."""

    name: str
    vehicle: Vehicle
    control: OdometryStream
    odom: DeadReckoning
    observations: Observations
    gps: GpsTrack
    scans: LaserScans | None = None
    landmarks: np.ndarray | None = None   # (M, 2) ground-truth landmark positions

    @property
    def start_time(self) -> float:
        firsts = [self.control.times[:1], self.observations.times[:1], self.gps.times[:1]]
        if self.scans is not None:
            firsts.append(self.scans.times[:1])
        return float(np.min(np.concatenate(firsts)))

    def message_counts(self) -> dict[str, int]:
        counts = {TOPIC_TF_STATIC: 1, TOPIC_ODOM: len(self.odom.times), TOPIC_TF: len(self.odom.times),
                  TOPIC_CONTROL: len(self.control), TOPIC_OBSERVATIONS: len(self.observations),
                  TOPIC_GT_POSITION: len(self.gps)}
        if self.scans is not None:
            counts[TOPIC_SCAN] = len(self.scans)
        if self.landmarks is not None:
            counts[TOPIC_GT_LANDMARKS] = 1
        return counts


def acfr_rates(speed, steering, vehicle: Vehicle = VEHICLE) -> tuple[np.ndarray, np.ndarray]:
    """Centre speed v_c = v_e / (1 - tan(alpha) H / L) and yaw rate v_c tan(alpha) / L.

    The formula is the filter's own (core.models.motion.acfr): one step of dt = 1 s
    from heading 0 moves the pose by (v_c, 0, yaw rate), so the bag's dead
    reckoning and the filter cannot drift apart.
    """
    speed, steering = np.broadcast_arrays(np.asarray(speed, dtype=np.float64),
                                          np.asarray(steering, dtype=np.float64))
    model = MotionConfig(model="acfr", wheelbase=vehicle.wheelbase, encoder_offset=vehicle.encoder_offset)
    control = np.stack([speed.reshape(-1), steering.reshape(-1)], axis=-1)
    moved, _, _ = motion.acfr(model, np.zeros((len(control), 3)), control, 1.0)
    return moved[:, 0].reshape(speed.shape), moved[:, 2].reshape(speed.shape)


def dead_reckon(control: OdometryStream, vehicle: Vehicle = VEHICLE,
                initial_pose=(0.0, 0.0, 0.0)) -> DeadReckoning:
    """Euler integration of the ACFR model; pose k is the pose at control.times[k]."""
    v_c, w = acfr_rates(control.speed, control.steering, vehicle)
    n = len(control.times)
    poses = np.empty((n, 3))
    if n == 0:
        return DeadReckoning(control.times, poses, v_c, w)
    dt = np.diff(control.times)
    phi = initial_pose[2] + np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])
    poses[:, 0] = initial_pose[0] + np.concatenate([[0.0], np.cumsum(v_c[:-1] * dt * np.cos(phi[:-1]))])
    poses[:, 1] = initial_pose[1] + np.concatenate([[0.0], np.cumsum(v_c[:-1] * dt * np.sin(phi[:-1]))])
    poses[:, 2] = np.arctan2(np.sin(phi), np.cos(phi))
    return DeadReckoning(control.times, poses, v_c, w)


def car_park_observations(scans: LaserScans, **beacon_kwargs) -> Observations:
    """extract_beacons() on every scan (empty groups kept)."""
    kwargs = {"max_range": scans.max_range, **beacon_kwargs}
    offsets = [0]
    rs, bs = [], []
    for r, inten in zip(scans.ranges, scans.intensities):
        d = extract_beacons(r, inten, scans.angle_min, scans.angle_increment, **kwargs)
        rs.append(d.range)
        bs.append(d.bearing)
        offsets.append(offsets[-1] + len(d))
    return Observations(scans.times.copy(), np.asarray(offsets, dtype=np.int64),
                        np.concatenate(rs) if rs else np.zeros(0),
                        np.concatenate(bs) if bs else np.zeros(0))


def car_park_streams(data: CarPark | None = None, data_dir=None, **beacon_kwargs) -> Streams:
    data = data if data is not None else load_car_park(data_dir)
    return Streams("car_park", data.vehicle, data.odometry, dead_reckon(data.odometry, data.vehicle),
                   car_park_observations(data.scans, **beacon_kwargs), data.gps,
                   scans=data.scans, landmarks=data.beacons)


def victoria_park_streams(data: VictoriaPark | None = None, data_dir=None,
                          tree_centre: bool = True) -> Streams:
    """``tree_centre``: range to the trunk centre (+ diameter / 2) instead of its surface."""
    data = data if data is not None else load_victoria_park(data_dir)
    trees = data.trees
    rng = trees.centre_range if tree_centre else trees.range.copy()
    obs = Observations(trees.times, trees.offsets, rng, trees.bearing)
    return Streams("victoria_park", data.vehicle, data.dr, dead_reckon(data.dr, data.vehicle), obs, data.gps)


STREAM_BUILDERS = {"car_park": car_park_streams, "victoria_park": victoria_park_streams}


def build_streams(name: str, data_dir=None) -> Streams:
    try:
        builder = STREAM_BUILDERS[name]
    except KeyError:
        raise ValueError(f"unknown dataset {name!r}; choose from {sorted(STREAM_BUILDERS)}") from None
    return builder(data_dir=data_dir)


def gps_frame_in_map(streams: Streams) -> tuple[float, float, float] | None:
    """Pose (x, y, yaw) of the ``gps`` frame in the ``map`` frame of a node started at (0, 0, 0).

    The node's map frame is then the base pose at the first motion input, which the
    odometry also starts from; its pose in the GPS frame is fitted exactly as the
    offline runner's ``--initial-pose gps`` does, and map -> gps is its inverse.
    None when the GPS track cannot give a heading.
    """
    from ...offline.evaluation import initial_pose_from_gps

    if len(streams.gps) < 2 or len(streams.control.times) == 0:
        return None
    try:
        start = initial_pose_from_gps(streams.gps.times, streams.gps.xy,
                                      (streams.vehicle.sensor_x, streams.vehicle.sensor_y),
                                      float(streams.control.times[0]), streams.odom.times, streams.odom.poses)
    except ValueError:
        return None
    c, s = np.cos(start.yaw), np.sin(start.yaw)
    # Inverse of (x, y, yaw): rotate the negated translation by -yaw.
    return (float(-c * start.x - s * start.y), float(s * start.x - c * start.y), float(-start.yaw))


def to_ns(t) -> np.ndarray:
    """Seconds -> integer nanoseconds (rounded)."""
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def message_schedule(streams: Streams) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Time order of all messages: (stamps_ns, topics, index within topic), sorted
    by stamp, then TOPIC_PRIORITY, then index."""
    t0 = streams.start_time
    per_topic = {TOPIC_TF_STATIC: np.array([t0]), TOPIC_CONTROL: streams.control.times,
                 TOPIC_ODOM: streams.odom.times, TOPIC_TF: streams.odom.times,
                 TOPIC_GT_POSITION: streams.gps.times,
                 TOPIC_OBSERVATIONS: streams.observations.times}
    if streams.landmarks is not None:
        per_topic[TOPIC_GT_LANDMARKS] = np.array([t0])
    if streams.scans is not None:
        per_topic[TOPIC_SCAN] = streams.scans.times
    return message_order({t: to_ns(times) for t, times in per_topic.items()}, TOPIC_PRIORITY)


# --------------------------------------------------------------------------- rosbags messages

class MessageFactory:
    """Builds rosbags message objects for the streams."""

    def __init__(self, streams: Streams, typestore=None, map_to_gps=None):
        self.s = streams
        self.map_to_gps = map_to_gps
        self.ts = typestore or jazzy_typestore()
        T = self.ts.types
        self.Time = T["builtin_interfaces/msg/Time"]
        self.Header = T["std_msgs/msg/Header"]
        self.Vector3 = T["geometry_msgs/msg/Vector3"]
        self.Point = T["geometry_msgs/msg/Point"]
        self.Quaternion = T["geometry_msgs/msg/Quaternion"]
        self.T = T

    def header(self, stamp_ns: int, frame: str):
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return self.Header(stamp=self.Time(sec=sec, nanosec=nsec), frame_id=frame)

    def _quat(self, yaw: float):
        x, y, z, w = yaw_to_xyzw(yaw)
        return self.Quaternion(x=x, y=y, z=z, w=w)

    def _cloud(self, stamp_ns: int, frame: str, columns: dict, layout):
        return build_message(self.T["sensor_msgs/msg/PointCloud2"], self.T["sensor_msgs/msg/PointField"],
                             self.header(stamp_ns, frame), columns, layout, raw_data=True)

    def _transform(self, stamp_ns: int, parent: str, child: str, x: float, y: float, yaw: float):
        T = self.T
        return T["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=self.Vector3(x=float(x), y=float(y), z=0.0), rotation=self._quat(float(yaw))))

    def tf_static(self, stamp_ns: int):
        v = self.s.vehicle
        transforms = [self._transform(stamp_ns, FRAME_BASE, FRAME_LASER, v.sensor_x, v.sensor_y, 0.0)]
        if self.map_to_gps is not None:
            transforms.append(self._transform(stamp_ns, FRAME_MAP, FRAME_GPS, *self.map_to_gps))
        return self.T["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def tf(self, stamp_ns: int, i: int):
        # odom -> base_link: the /odom pose again, as the odometry source would broadcast it.
        x, y, yaw = self.s.odom.poses[i]
        return self.T["tf2_msgs/msg/TFMessage"](
            transforms=[self._transform(stamp_ns, FRAME_ODOM, FRAME_BASE, x, y, yaw)])

    def gt_landmarks(self, stamp_ns: int):
        lm = self.s.landmarks
        cols = {"x": lm[:, 0], "y": lm[:, 1], "z": np.zeros(len(lm)), "id": np.arange(len(lm), dtype=np.int32)}
        return self._cloud(stamp_ns, FRAME_GPS, cols, GROUND_TRUTH_LANDMARK_FIELDS)

    def twist(self, stamp_ns: int, linear_x: float, angular_z: float):
        """A TwistStamped in the base frame: the /control message of every converter."""
        T = self.T
        return T["geometry_msgs/msg/TwistStamped"](
            header=self.header(stamp_ns, FRAME_BASE),
            twist=T["geometry_msgs/msg/Twist"](linear=self.Vector3(x=float(linear_x), y=0.0, z=0.0),
                                               angular=self.Vector3(x=0.0, y=0.0, z=float(angular_z))))

    def control(self, stamp_ns: int, i: int):
        return self.twist(stamp_ns, self.s.control.speed[i], self.s.control.steering[i])

    def odom(self, stamp_ns: int, i: int):
        T, o = self.T, self.s.odom
        x, y, yaw = (float(v) for v in o.poses[i])
        pose = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=self.Point(x=x, y=y, z=0.0), orientation=self._quat(yaw)),
            covariance=np.zeros(36))
        twist = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=self.Vector3(x=float(o.speed[i]), y=0.0, z=0.0),
                                               angular=self.Vector3(x=0.0, y=0.0, z=float(o.yaw_rate[i]))),
            covariance=np.zeros(36))
        return T["nav_msgs/msg/Odometry"](header=self.header(stamp_ns, FRAME_ODOM),
                                          child_frame_id=FRAME_BASE, pose=pose, twist=twist)

    def gt_position(self, stamp_ns: int, i: int):
        g = self.s.gps
        return self.T["geometry_msgs/msg/PointStamped"](
            header=self.header(stamp_ns, FRAME_GPS), point=self.Point(x=float(g.x[i]), y=float(g.y[i]), z=0.0))

    def scan(self, stamp_ns: int, i: int):
        sc = self.s.scans
        r = sc.ranges[i].astype(np.float32)
        r[~(sc.ranges[i] < sc.max_range)] = np.inf
        period = float(np.median(np.diff(sc.times))) if len(sc.times) > 1 else 0.0
        n = r.size
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp_ns, FRAME_LASER), angle_min=float(sc.angle_min),
            angle_max=float(sc.angle_min + (n - 1) * sc.angle_increment),
            angle_increment=float(sc.angle_increment), time_increment=0.0, scan_time=period,
            range_min=0.0, range_max=float(sc.max_range), ranges=r,
            intensities=sc.intensities[i].astype(np.float32))

    def observations(self, stamp_ns: int, i: int):
        _, rng, brg = self.s.observations.scan(i)
        return self._cloud(stamp_ns, FRAME_LASER, observation_columns(rng, brg), OBSERVATION_FIELDS)

    def build(self, topic: str, stamp_ns: int, i: int):
        if topic == TOPIC_TF_STATIC:
            return self.tf_static(stamp_ns)
        if topic == TOPIC_GT_LANDMARKS:
            return self.gt_landmarks(stamp_ns)
        return {TOPIC_CONTROL: self.control, TOPIC_ODOM: self.odom, TOPIC_TF: self.tf,
                TOPIC_GT_POSITION: self.gt_position,
                TOPIC_SCAN: self.scan, TOPIC_OBSERVATIONS: self.observations}[topic](stamp_ns, i)


def iter_messages(streams: Streams, typestore=None, map_to_gps=None):
    """Yield (stamp_ns, topic, msgtype, rosbags message) in time order; ``map_to_gps``:
    (x, y, yaw) of the static map -> gps transform, None to leave it out."""
    factory = MessageFactory(streams, typestore, map_to_gps)
    stamps, topics, index = message_schedule(streams)
    for stamp, topic, i in zip(stamps.tolist(), topics, index.tolist()):
        yield stamp, topic, MSGTYPES[topic], factory.build(topic, stamp, i)


def write_bag(streams: Streams, output, storage: str = "mcap", progress: bool = True,
              overwrite: bool = False, stream=None, map_to_gps: bool = True) -> dict[str, int]:
    """Write the streams to a ROS 2 bag directory ``output``; returns messages per topic.
    ``map_to_gps``: add the static map -> gps transform (see the module docstring)."""
    output = Path(output)
    clear_bag_directory(output, overwrite)
    ts = jazzy_typestore()
    gps_pose = gps_frame_in_map(streams) if map_to_gps else None
    return write_topics(output, iter_messages(streams, ts, gps_pose), streams.message_counts(), MSGTYPES,
                        LATCHED_TOPICS, ts, storage, f"{streams.name} -> {output.name}", progress, stream)


def convert(name: str, output, data_dir=None, storage: str = "mcap", progress: bool = True,
            overwrite: bool = False, map_to_gps: bool = True) -> dict[str, int]:
    return write_bag(build_streams(name, data_dir), output, storage=storage, progress=progress,
                     overwrite=overwrite, map_to_gps=map_to_gps)


def dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())
