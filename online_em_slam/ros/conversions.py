"""Conversions between ROS messages and the core's types (no node state here).

Every function that writes floats into a message refuses non-finite values
(returns None or skips the row) so that no NaN reaches a topic.
"""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import (Point, Pose, PoseArray, PoseStamped, PoseWithCovarianceStamped,
                               Quaternion, TransformStamped)
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..cloud import LANDMARK_FIELDS, OBSERVATION_FIELDS, CloudFormatError, decode_message, encode
from ..core.angles import wrap_angle
from ..core.types import LandmarkMap, Observations, PoseEstimate

__all__ = ["CloudFormatError", "stamp_to_sec", "sec_to_stamp", "yaw_to_quaternion", "quaternion_to_yaw", "odometry_yaw",
           "observations_from_cloud", "observations_to_cloud", "landmarks_to_cloud", "landmarks_to_markers",
           "pose_to_msg", "particles_to_msg", "pose2d_compose", "pose2d_inverse", "transform_msg",
           "COVARIANCE_INDEX"]

# (row, col) of the 3x3 (x, y, yaw) covariance -> index in the 6x6 row-major ROS covariance.
COVARIANCE_INDEX = {(0, 0): 0, (0, 1): 1, (0, 2): 5, (1, 0): 6, (1, 1): 7, (1, 2): 11,
                    (2, 0): 30, (2, 1): 31, (2, 2): 35}


def stamp_to_sec(stamp) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def sec_to_stamp(seconds: float) -> TimeMsg:
    """builtin_interfaces/Time from seconds (clamped to the message's range, >= 0)."""
    nanoseconds = max(0, min(int(round(float(seconds) * 1e9)), (2 ** 31 - 1) * 10 ** 9))
    return TimeMsg(sec=nanoseconds // 10 ** 9, nanosec=nanoseconds % 10 ** 9)


def yaw_to_quaternion(yaw: float) -> Quaternion:
    half = 0.5 * float(yaw)
    return Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


# |q|^2 may differ from 1 by this much before a quaternion counts as unnormalised
# (tf2's QUATERNION_NORMALIZATION_TOLERANCE); float32 round-off is far below it.
QUATERNION_TOLERANCE = 1e-2
# Below this norm, or when the yaw is undefined (pitch +-90 degrees), a quaternion is degenerate.
DEGENERATE_QUATERNION = 1e-6


def _yaw_terms(q) -> tuple[float, float, float]:
    """Scale-invariant yaw terms (sin part, cos part) and |q|, overflow-free.

    Dividing by the largest component first keeps 1e300 components finite, and
    using w^2 + x^2 - y^2 - z^2 instead of 1 - 2 (y^2 + z^2) makes the yaw that of
    the normalised quaternion whatever the scale.
    """
    v = np.array([q.x, q.y, q.z, q.w], dtype=float)
    scale = float(np.max(np.abs(v))) if np.all(np.isfinite(v)) else math.nan
    if not scale > 0.0:
        return math.nan if math.isnan(scale) else 0.0, 0.0, scale
    x, y, z, w = v / scale
    norm = scale * math.sqrt(x * x + y * y + z * z + w * w)
    return 2.0 * (w * z + x * y), w * w + x * x - y * y - z * z, norm


def quaternion_to_yaw(q) -> float:
    """Yaw (rotation about z) of a quaternion of any non-zero scale; the roll/pitch parts are ignored."""
    sin_part, cos_part, _ = _yaw_terms(q)
    return math.atan2(sin_part, cos_part)


def odometry_yaw(q) -> tuple[float, str | None]:
    """Yaw of an odometry orientation and what was wrong with the quaternion.

    Returns (yaw, None) for a unit quaternion, (yaw of the normalised
    quaternion, "unnormalised_quaternion") when |q|^2 is off by more than
    QUATERNION_TOLERANCE, (nan, "degenerate_quaternion") when no yaw is defined
    (zero or tiny norm, pitch +-90 degrees), and (nan, None) for non-finite
    components (the caller's non-finite check handles those).
    """
    sin_part, cos_part, norm = _yaw_terms(q)
    if math.isnan(norm):
        return math.nan, None
    scaled_norm = math.hypot(sin_part, cos_part)
    if norm < DEGENERATE_QUATERNION or scaled_norm < DEGENERATE_QUATERNION:
        return math.nan, "degenerate_quaternion"
    problem = "unnormalised_quaternion" if abs(norm * norm - 1.0) > QUATERNION_TOLERANCE else None
    return math.atan2(sin_part, cos_part), problem


def _finite(*values) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)


# ----------------------------------------------------------------- observations
FLOAT_FIELDS = ("range", "bearing", "range_std", "bearing_std")
MAX_ID = 2 ** 31 - 1          # ids are published as int32 (map cloud, Marker.id)
# Bearings beyond one extra turn are not a sensor's angle convention ([0, 2 pi) or
# (-pi, pi]) but garbage; wrapping 1e20 rad would give an arbitrary direction.
MAX_ABS_BEARING = 2.0 * math.pi


def _float_column(columns: dict, name: str) -> np.ndarray | None:
    """A measurement column; integer types are refused: a UINT8 ``range`` is not metres."""
    if name not in columns:
        return None
    column = columns[name]
    if column.dtype.kind != "f":
        raise CloudFormatError(f"field {name!r} has integer type {column.dtype}; "
                               f"{', '.join(FLOAT_FIELDS)} must be FLOAT32 or FLOAT64")
    return column.astype(float)


def _ids_column(columns: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """ids as int64 and a mask of valid ones: -1 (unknown) or an integer in [0, MAX_ID].

    A float id field holding NaN, 1e20 or 2.5, an id >= 2^31 (it would be published
    negative and collide with another marker) or below -1 is invalid, not unknown:
    associating such an observation by likelihood would hide a broken publisher.
    """
    if "id" not in columns:
        return np.full(n, -1, dtype=np.int64), np.ones(n, dtype=bool)
    raw = columns["id"]
    if raw.dtype.kind not in "iuf":
        raise CloudFormatError(f"field 'id' has type {raw.dtype}")
    values = raw.astype(float) if raw.dtype.kind == "f" else raw.astype(np.int64).astype(float)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values == np.round(values)) & (values >= -1) & (values <= MAX_ID)
    ids = np.where(valid, values, -1).astype(np.int64)
    return ids, valid


def _count(drops, reason: str, mask: np.ndarray) -> None:
    if drops is not None and mask.any():
        drops[reason] += int(mask.sum())


def observations_from_cloud(msg: PointCloud2, drops=None) -> Observations:
    """Observations from a PointCloud2 with fields range, bearing [, id, range_std, bearing_std].

    Raises CloudFormatError for missing fields, inconsistent sizes or measurement
    fields of integer type.  Observations with an invalid id (see _ids_column), a
    zero range or a bearing beyond +-2 pi are left out and counted in ``drops``
    (a Counter, by reason: invalid_id, zero_range, bearing_out_of_range).  Other
    values are passed on (the core drops and counts non-finite and negative
    ranges); bearings are wrapped to (-pi, pi].
    """
    columns = decode_message(msg, required=("range", "bearing"))
    ranges, bearings = _float_column(columns, "range"), _float_column(columns, "bearing")
    std = {name: _float_column(columns, name) for name in ("range_std", "bearing_std")}
    ids, valid_id = _ids_column(columns, ranges.shape[0])
    finite = np.isfinite(bearings)
    with np.errstate(invalid="ignore"):
        wild = finite & (np.abs(bearings) > MAX_ABS_BEARING)
    zero = ranges == 0.0
    _count(drops, "invalid_id", ~valid_id)
    _count(drops, "zero_range", valid_id & zero)
    _count(drops, "bearing_out_of_range", valid_id & ~zero & wild)
    keep = valid_id & ~zero & ~wild
    bearings = np.where(finite, wrap_angle(np.where(finite & keep, bearings, 0.0)), bearings)
    observations = Observations(ranges, bearings, ids, std["range_std"], std["bearing_std"])
    return observations if keep.all() else observations.subset(keep)


def _point_fields(specs) -> list[PointField]:
    return [PointField(name=s.name, offset=s.offset, datatype=s.datatype, count=s.count) for s in specs]


def _cloud(header: Header, columns: dict, layout) -> PointCloud2:
    specs, point_step, data = encode(columns, layout)
    n = len(data) // point_step if point_step else 0
    msg = PointCloud2(header=header, height=1, width=n, fields=_point_fields(specs), is_bigendian=False,
                      point_step=point_step, row_step=point_step * n, is_dense=True)
    msg.data = data
    return msg


def observations_to_cloud(header: Header, ranges, bearings, ids=None, range_std=None,
                          bearing_std=None) -> PointCloud2:
    """PointCloud2 in the OBSERVATION_FIELDS layout (x, y, z in the sensor frame)."""
    ranges = np.asarray(ranges, dtype=float)
    bearings = np.asarray(bearings, dtype=float)
    n = ranges.shape[0]
    with np.errstate(invalid="ignore"):      # non-finite inputs stay non-finite (tests, fuzzing)
        x, y = ranges * np.cos(bearings), ranges * np.sin(bearings)
    columns = {"x": x, "y": y, "z": np.zeros(n),
               "range": ranges, "bearing": bearings,
               "id": np.full(n, -1) if ids is None else np.asarray(ids),
               "range_std": np.full(n, np.nan) if range_std is None else np.asarray(range_std),
               "bearing_std": np.full(n, np.nan) if bearing_std is None else np.asarray(bearing_std)}
    return _cloud(header, columns, OBSERVATION_FIELDS)


# ----------------------------------------------------------------- landmark map
def _publishable_rows(landmarks: LandmarkMap) -> tuple[np.ndarray, dict[str, int]]:
    """Rows that can be published, and the others counted by reason.

    Ids outside [0, 2^31 - 1] are left out rather than wrapped: the map cloud's id
    field and Marker.id are int32, and a wrapped id would be negative or collide
    with another landmark's.
    """
    pos = np.asarray(landmarks.positions, dtype=float).reshape(-1, 2)
    cov = np.asarray(landmarks.covariances, dtype=float).reshape(-1, 2, 2)
    ids = np.asarray(landmarks.ids).reshape(-1)
    finite = np.isfinite(pos).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    id_ok = (ids >= 0) & (ids <= MAX_ID)
    skipped = {"non_finite_landmark": int((~finite).sum()),
               "landmark_id_out_of_range": int((finite & ~id_ok).sum())}
    return finite & id_ok, {k: v for k, v in skipped.items() if v}


def landmarks_to_cloud(header: Header, landmarks: LandmarkMap) -> tuple[PointCloud2, dict[str, int]]:
    """The map as PointCloud2 (LANDMARK_FIELDS) and the rows left out, counted by reason."""
    keep, skipped = _publishable_rows(landmarks)
    pos = np.asarray(landmarks.positions, dtype=float).reshape(-1, 2)[keep]
    cov = np.asarray(landmarks.covariances, dtype=float).reshape(-1, 2, 2)[keep]
    columns = {"x": pos[:, 0], "y": pos[:, 1], "z": np.zeros(len(pos)),
               "id": np.asarray(landmarks.ids)[keep], "cov_xx": cov[:, 0, 0], "cov_xy": cov[:, 0, 1],
               "cov_yy": cov[:, 1, 1], "n_obs": np.asarray(landmarks.n_obs)[keep]}
    return _cloud(header, columns, LANDMARK_FIELDS), skipped


def ellipse_points(mean, cov, n_sigma: float, n_points: int = 24) -> np.ndarray | None:
    """Closed polyline (n_points + 1, 2) of the n_sigma covariance ellipse, or None if degenerate."""
    cov = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    if not _finite(mean, cov):
        return None
    values, vectors = np.linalg.eigh(cov)
    radii = n_sigma * np.sqrt(np.clip(values, 0.0, None))
    t = np.linspace(0.0, 2.0 * np.pi, n_points + 1)
    unit = np.stack([np.cos(t), np.sin(t)], axis=1) * radii
    points = unit @ vectors.T + np.asarray(mean, dtype=float)
    return points if _finite(points) else None


def landmarks_to_markers(header: Header, landmarks: LandmarkMap, n_sigma: float = 2.0,
                         namespace: str = "landmarks") -> MarkerArray:
    """A DELETEALL, then per landmark a LINE_STRIP covariance ellipse and a TEXT id.

    Confirmed landmarks are green, tentative ones orange.
    """
    array = MarkerArray()
    array.markers.append(Marker(header=header, action=Marker.DELETEALL))
    keep, _ = _publishable_rows(landmarks)
    confirmed = np.asarray(landmarks.confirmed, dtype=bool).reshape(-1)
    for row in np.flatnonzero(keep):
        mean = landmarks.positions[row]
        points = ellipse_points(mean, landmarks.covariances[row], n_sigma)
        if points is None:
            continue
        lid = int(landmarks.ids[row])              # in int32 range: _publishable_rows
        color = (ColorRGBA(r=0.1, g=0.8, b=0.2, a=1.0) if confirmed[row]
                 else ColorRGBA(r=1.0, g=0.55, b=0.0, a=0.8))
        ellipse = Marker(header=header, ns=namespace + "/ellipses", id=lid, type=Marker.LINE_STRIP,
                         action=Marker.ADD, color=color, frame_locked=False)
        ellipse.pose.orientation.w = 1.0
        ellipse.scale.x = 0.05
        ellipse.points = [Point(x=float(x), y=float(y), z=0.0) for x, y in points]
        text = Marker(header=header, ns=namespace + "/ids", id=lid, type=Marker.TEXT_VIEW_FACING,
                      action=Marker.ADD, color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0), text=str(lid))
        text.pose.position = Point(x=float(mean[0]), y=float(mean[1]), z=0.5)
        text.pose.orientation.w = 1.0
        text.scale.z = 0.6
        array.markers.extend((ellipse, text))
    return array


# ----------------------------------------------------------------- poses
def pose_msg(x: float, y: float, yaw: float) -> Pose:
    pose = Pose()
    pose.position = Point(x=float(x), y=float(y), z=0.0)
    pose.orientation = yaw_to_quaternion(yaw)
    return pose


def pose_to_msg(header: Header, estimate: PoseEstimate) -> PoseWithCovarianceStamped | None:
    """PoseWithCovarianceStamped of the (x, y, yaw) estimate; None if anything is non-finite."""
    mean = np.asarray(estimate.mean, dtype=float).reshape(3)
    cov = np.asarray(estimate.covariance, dtype=float).reshape(3, 3)
    if not _finite(mean, cov):
        return None
    msg = PoseWithCovarianceStamped(header=header)
    msg.pose.pose = pose_msg(*mean)
    covariance = [0.0] * 36
    for (i, j), index in COVARIANCE_INDEX.items():
        covariance[index] = float(cov[i, j])
    msg.pose.covariance = covariance
    return msg


def pose_stamped(header: Header, mean) -> PoseStamped | None:
    mean = np.asarray(mean, dtype=float).reshape(3)
    if not _finite(mean):
        return None
    return PoseStamped(header=header, pose=pose_msg(*mean))


def particles_to_msg(header: Header, poses: np.ndarray) -> PoseArray:
    """PoseArray of the particles (non-finite particles are left out)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    poses = poses[np.isfinite(poses).all(axis=1)]
    return PoseArray(header=header, poses=[pose_msg(*p) for p in poses])


# ----------------------------------------------------------------- 2-D transforms
def pose2d_compose(a, b) -> np.ndarray:
    """a (+) b: pose b expressed in a's frame, mapped to a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2])])


def pose2d_inverse(a) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap_angle(-a[2])])


def transform_msg(stamp: TimeMsg, parent: str, child: str, pose) -> TransformStamped | None:
    """TransformStamped T(parent <- child) from a 2-D pose of child in parent; None if non-finite."""
    pose = np.asarray(pose, dtype=float).reshape(3)
    if not _finite(pose):
        return None
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    msg.transform.translation.x = float(pose[0])
    msg.transform.translation.y = float(pose[1])
    msg.transform.translation.z = 0.0
    msg.transform.rotation = yaw_to_quaternion(pose[2])
    return msg
