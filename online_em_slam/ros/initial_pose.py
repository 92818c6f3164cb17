"""``/initialpose`` (RViz's "2D Pose Estimate", AMCL's topic): the pose and its spread.

The estimator keeps its map and restarts its particles around the given pose
(``OnlineEMSlam.set_pose``), so a user can relocalise the robot against a
loaded map or correct a bad start without losing the map.
"""
from __future__ import annotations

import math

import numpy as np

from . import conversions as conv


def pose_and_std(msg, default_std) -> tuple[np.ndarray | None, np.ndarray, str | None]:
    """(pose (3,) or None, std (3,), problem or None) of a PoseWithCovarianceStamped.

    The standard deviations come from the 6x6 covariance (x at 0, y at 7, yaw at
    35); zero, negative or non-finite entries fall back to ``default_std``.
    """
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    yaw, problem = conv.odometry_yaw(q)
    if problem == "degenerate_quaternion":
        return None, np.asarray(default_std, dtype=float), problem
    pose = np.array([p.x, p.y, yaw], dtype=float)
    if not np.all(np.isfinite(pose)):
        return None, np.asarray(default_std, dtype=float), "non_finite_initial_pose"
    cov = msg.pose.covariance
    std = np.array([math.sqrt(cov[i]) if math.isfinite(cov[i]) and cov[i] > 0 else d
                    for i, d in zip((0, 7, 35), default_std)], dtype=float)
    return pose, std, None
