"""Planar yaw <-> quaternion, the one copy for the node, the offline runner and the tools.

No ROS import: the node passes rclpy messages, the offline tools rosbags
messages; both have x, y, z, w attributes.  The checks (scale, degenerate
quaternions) are the node's, so an offline run reads a bag's odometry exactly
as the node reads the topic.
"""
from __future__ import annotations

import math

__all__ = ["QUATERNION_TOLERANCE", "DEGENERATE_QUATERNION", "yaw_to_xyzw", "quaternion_to_yaw", "odometry_yaw"]

# |q|^2 may differ from 1 by this much before a quaternion counts as unnormalised
# (tf2's QUATERNION_NORMALIZATION_TOLERANCE); float32 round-off is far below it.
QUATERNION_TOLERANCE = 1e-2
# Below this norm, or when the yaw is undefined (pitch +-90 degrees), a quaternion is degenerate.
DEGENERATE_QUATERNION = 1e-6


def yaw_to_xyzw(yaw: float) -> tuple[float, float, float, float]:
    """Components (x, y, z, w) of the rotation by ``yaw`` about z."""
    half = 0.5 * float(yaw)
    return 0.0, 0.0, math.sin(half), math.cos(half)


def _yaw_terms(q) -> tuple[float, float, float]:
    """Scale-invariant yaw terms (sin part, cos part) and |q|, overflow-free.

    Dividing by the largest component first keeps 1e300 components finite, and
    using w^2 + x^2 - y^2 - z^2 instead of 1 - 2 (y^2 + z^2) makes the yaw that of
    the normalised quaternion whatever the scale.
    """
    # Plain floats, not a numpy array: this runs once per odometry message, and numpy's per-call
    # overhead made it 8.7 us against 1.8; the arithmetic is the same, value for value.
    v = (float(q.x), float(q.y), float(q.z), float(q.w))
    scale = max(abs(c) for c in v) if all(math.isfinite(c) for c in v) else math.nan
    if not scale > 0.0:
        return math.nan if math.isnan(scale) else 0.0, 0.0, scale
    x, y, z, w = (c / scale for c in v)
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
