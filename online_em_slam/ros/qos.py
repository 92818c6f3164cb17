"""The node's QoS profiles: best-effort-compatible sensor inputs, latched map and pose."""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def input_qos(reliability: str, depth: int) -> QoSProfile:
    """Sensor inputs: best_effort (the default) matches every publisher, as REP-2003 and
    slam_toolbox do; reliable keeps every message (KEEP_ALL: a full queue makes a reliable
    publisher wait instead of losing), for lossless bag replay."""
    if reliability == "reliable":
        return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def latched_qos() -> QoSProfile:
    """Map and latest pose: depth 1, reliable, transient local (a late subscriber such as RViz gets them)."""
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
