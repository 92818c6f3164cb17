"""The distributed fleet's segment messages as bytes (no ROS import): the one encoder and decoder.

A :class:`~online_em_slam.core.em.segment_message.SegmentMessage` travels between nodes
as the data of a std_msgs/UInt8MultiArray (docs/NODE.md, "Distributed fleet"): an
uncompressed ``.npz`` archive (numpy's own format, read without pickle) whose arrays
are the message's fields plus ``format``, ``robot`` (the robot's name: nodes may list
their robots in different orders) and ``session`` (a number the sending estimator drew
when it started, so that a node restarted from sequence 1 is told from a duplicate).
The symmetric ``local`` is sent whole: at MRCLAM's segment length it is about 16 kB.

:func:`decode` refuses anything that is not a well-formed message of this format with
a ValueError naming what is wrong; the receiver counts it and goes on.
"""
from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass

import numpy as np

from ..core.em.segment_factors import POSE_DIM, SegmentSystem
from ..core.em.segment_message import SegmentMessage

FORMAT = "online_em_slam.segment.v1"
_SEGMENT_FIELDS = ("local", "vector", "key", "pose", "counts")


@dataclass
class Envelope:
    """A decoded message with where it comes from: ``robot`` (name) and the sender's ``session``."""

    robot: str
    session: int
    message: SegmentMessage


def encode(message: SegmentMessage, robot: str, session: int) -> bytes:
    """``message`` of robot ``robot`` (its name) from the estimator started as ``session``."""
    arrays = {"format": np.array(FORMAT), "robot": np.array(robot), "session": np.array(session, np.int64),
              "sequence": np.array(message.sequence, np.int64), "ids": np.asarray(message.ids, np.int64),
              "theta": np.asarray(message.theta, float).reshape(-1, 2)}
    if message.segment is not None:
        arrays.update({f"segment_{name}": np.asarray(getattr(message.segment, name))
                       for name in _SEGMENT_FIELDS})
    else:
        arrays.update(pose=np.asarray(message.pose, float), pose_std=np.asarray(message.pose_std, float))
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


def decode(data: bytes) -> Envelope:
    """The message in ``data``; its ``robot`` index is -1 until the receiver sets its own index of
    the robot named in the envelope."""
    try:
        with np.load(io.BytesIO(bytes(data)), allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"not a segment message ({error})") from None
    if str(arrays.get("format", "")) != FORMAT:
        raise ValueError(f"not a segment message of format {FORMAT}")
    try:
        envelope = Envelope(str(_field(arrays, "robot")), int(_field(arrays, "session")), _message(arrays, -1))
    except (TypeError, ValueError) as error:
        raise ValueError(f"segment message: a field of the wrong type or without it ({error})") from None
    _check(envelope.message)
    return envelope


def _field(arrays: dict, name: str) -> np.ndarray:
    if name not in arrays:
        raise ValueError(f"segment message without {name!r}")
    return arrays[name]


def _message(arrays: dict, robot_index: int) -> SegmentMessage:
    ids, theta = _field(arrays, "ids").astype(np.int64), _field(arrays, "theta").astype(float)
    sequence = int(_field(arrays, "sequence"))
    if "segment_local" not in arrays:
        return SegmentMessage(robot_index, sequence, None, ids, theta, _field(arrays, "pose").astype(float),
                              _field(arrays, "pose_std").astype(float))
    parts = {name: _field(arrays, f"segment_{name}") for name in _SEGMENT_FIELDS}
    segment = SegmentSystem(parts["local"].astype(float), parts["vector"].astype(float), parts["key"].astype(float),
                            parts["pose"].astype(float), np.arange(ids.size), parts["counts"].astype(np.int64))
    return SegmentMessage(robot_index, sequence, segment, ids, theta)


def _check(message: SegmentMessage) -> None:
    """Shapes that fit together, finite values, a positive sequence number."""
    S = message.ids.size
    if message.sequence < 1 or message.theta.shape != (S, 2) or not np.isfinite(message.theta).all():
        raise ValueError("segment message: bad sequence, or landmark estimates that do not fit its ids")
    if len(np.unique(message.ids)) != S:
        raise ValueError("segment message: a landmark id appears twice")
    segment = message.segment
    if segment is None:
        if message.pose.shape != (POSE_DIM,) or message.pose_std.shape != (POSE_DIM,) \
                or not (np.isfinite(message.pose).all() and (message.pose_std >= 0).all()):
            raise ValueError("segment message: a restart without a finite pose and std")
        return
    n = segment.local.shape[0] if segment.local.ndim == 2 else -1
    shapes_fit = (segment.local.shape == (n, n) and segment.vector.shape == (n,) and segment.counts.shape == (S,)
                  and segment.key.shape == (POSE_DIM,) and segment.pose.shape == (POSE_DIM,)
                  and n > 2 * S and (n - 2 * S) % POSE_DIM == 0)
    if not shapes_fit:
        raise ValueError("segment message: the factor's shapes do not fit its landmarks")
    if not all(np.isfinite(a).all() for a in (segment.local, segment.vector, segment.key, segment.pose)):
        raise ValueError("segment message: a value that is not finite")
