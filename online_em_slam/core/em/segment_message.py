"""What a node sends the others so that they share its robot's map information (docs/METHOD.md,
"Fleet mode", "Distributed").

A closed segment's factor (segment_factors.SegmentSystem) is the robot's whole
contribution to the map's system: its landmarks are in absolute coordinates and its
poses are integrated out when it is folded in, so any node holding the same key block
adds it exactly.  Sent with the landmarks' ids (rows differ from node to node), the
sender's estimates (where a landmark new to the receiver starts) and a sequence number
per robot (a gap means a lost message, see ObservedInformationEM.fold_remote).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .segment_factors import SegmentSystem


@dataclass
class SegmentMessage:
    """``robot``'s ``sequence``-th message (from 1): a closed segment, or (``segment`` None) its
    key pose restarted at ``pose`` with prior std ``pose_std`` (an initial-pose message, a
    relocalisation: no motion links it to the old key)."""

    robot: int
    sequence: int
    segment: SegmentSystem | None
    ids: np.ndarray                    # (S,) the ids of the segment's landmarks, in its order
    theta: np.ndarray                  # (S, 2) the sender's estimates of them
    pose: np.ndarray | None = None     # restart: the new key pose (3,)
    pose_std: np.ndarray | None = None  # restart: its prior std (3,)
