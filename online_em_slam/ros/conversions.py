"""Conversions between ROS messages and the core's types (no node state here).

Every function that writes floats into a message refuses non-finite values
(returns None or skips the row) so that no NaN reaches a topic.
"""
from __future__ import annotations

import math
import time

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import (Point, Pose, PoseArray, PoseStamped, PoseWithCovarianceStamped,
                               Quaternion, TransformStamped)
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..messages.cloud import (LANDMARK_FIELDS, MAX_ID, OBSERVATION_FIELDS, CloudFormatError, build_message,
                              observations_from_message)
from ..core.models.angles import wrap_angle
from ..core.types import LandmarkMap, Observations, PoseEstimate
from ..messages.quaternion import (DEGENERATE_QUATERNION, QUATERNION_TOLERANCE, odometry_yaw,  # re-exported
                                   quaternion_to_yaw, yaw_to_xyzw)

__all__ = ["CloudFormatError", "stamp_to_sec", "sec_to_stamp", "yaw_to_quaternion", "quaternion_to_yaw", "odometry_yaw",
           "observations_from_cloud", "observations_to_cloud", "landmarks_to_cloud", "landmarks_to_markers",
           "pose_to_msg", "particles_to_msg", "pose2d_compose", "pose2d_inverse", "transform_msg",
           "COVARIANCE_INDEX", "DEGENERATE_QUATERNION", "QUATERNION_TOLERANCE"]

# (row, col) of the 3x3 (x, y, yaw) covariance -> index in the 6x6 row-major ROS covariance.
COVARIANCE_INDEX = {(0, 0): 0, (0, 1): 1, (0, 2): 5, (1, 0): 6, (1, 1): 7, (1, 2): 11,
                    (2, 0): 30, (2, 1): 31, (2, 2): 35}


def stamp_to_sec(stamp) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def queue_wait(info) -> float:
    """Seconds a message waited between its reception by the middleware and now (its MessageInfo's
    ``received_timestamp``, system clock ns); 0 where the middleware does not say."""
    received = info.get("received_timestamp") if info else None
    if not received:
        return 0.0
    return max(time.time_ns() - int(received), 0) * 1e-9


def sec_to_stamp(seconds: float) -> TimeMsg:
    """builtin_interfaces/Time from seconds (clamped to the message's range, >= 0)."""
    nanoseconds = max(0, min(int(round(float(seconds) * 1e9)), (2 ** 31 - 1) * 10 ** 9))
    return TimeMsg(sec=nanoseconds // 10 ** 9, nanosec=nanoseconds % 10 ** 9)


def yaw_to_quaternion(yaw: float) -> Quaternion:
    x, y, z, w = yaw_to_xyzw(yaw)
    return Quaternion(x=x, y=y, z=z, w=w)


def _finite(*values) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)


# ----------------------------------------------------------------- observations
def observations_from_cloud(msg: PointCloud2, drops=None) -> Observations:
    """The node's reader of observation clouds: :func:`online_em_slam.messages.cloud.observations_from_message`."""
    return observations_from_message(msg, drops)


def _cloud(header: Header, columns: dict, layout) -> PointCloud2:
    return build_message(PointCloud2, PointField, header, columns, layout)


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
