"""The estimate's frame against the ground truth's, for scoring a run.

An estimator's map frame is its initial pose: started at P, it places the robot at P
and everything else relative to it.  Ground truth lives in its own frame (the GPS
frame for the KTH data, the motion-capture frame for MRCLAM), where the robot started
at G (:func:`online_em_slam.offline.runner.truth_start`).  Scoring an estimate in
the ground-truth frame is meaningful only when P is (near) G; otherwise every figure
measures the difference of the frames, not the run (a Car Park run started at the
params file's (0, 0, 0): 1/15 beacons "mapped", trajectory error 22 m).

:func:`check_frame` decides which case a run is in and returns the motion
T(truth <- estimate) that carries the estimate into the ground-truth frame:

* the initial pose came from the ground truth (``--initial-pose ground_truth`` or
  ``gps``, or ``auto`` choosing them): same frame, identity;
* it came from elsewhere (params file, command line) and lies within the match gate
  and :data:`SAME_FRAME_HEADING_DEG` of G: taken as a pose given in the ground-truth
  frame, identity (its error is part of the run's error);
* farther: the frames differ; T = G P^-1 (as ``online-em-slam evaluate`` does for a
  recorded node run), so the estimate is scored as if it had started at G, and the
  metrics say so;
* no ground-truth start (no GPS, no ground-truth pose): cannot be checked; identity,
  and the metrics say the frames are assumed to agree (the landmark *shape* error does
  not depend on the frame).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

# A pose from outside the ground truth within this heading (and the match gate in position)
# of the ground truth's start is taken as given in the ground-truth frame.
SAME_FRAME_HEADING_DEG = 10.0


def compose(a, b) -> np.ndarray:
    """2-D pose composition a (+) b for a = (x, y, yaw) and b (n, 3)."""
    b = np.asarray(b, dtype=float).reshape(-1, 3)
    c, s = math.cos(a[2]), math.sin(a[2])
    out = np.column_stack([a[0] + c * b[:, 0] - s * b[:, 1], a[1] + s * b[:, 0] + c * b[:, 1], a[2] + b[:, 2]])
    out[:, 2] = np.arctan2(np.sin(out[:, 2]), np.cos(out[:, 2]))
    return out


def inverse(p) -> tuple[float, float, float]:
    c, s = math.cos(p[2]), math.sin(p[2])
    return (-c * p[0] - s * p[1], s * p[0] - c * p[1], -p[2])


@dataclass
class FrameCheck:
    """Result of :func:`check_frame` (metrics.json ``frame``)."""

    initial_pose_source: str
    same_frame: bool | None            # None: no ground-truth start to check against
    to_truth: tuple[float, float, float]  # T(truth <- estimate) applied before scoring
    offset_m: float | None = None      # |position of P - position of G|
    offset_deg: float | None = None    # heading of P - heading of G, wrapped
    truth_start_source: str | None = None
    note: str = ""

    @property
    def moved(self) -> bool:
        return self.to_truth != (0.0, 0.0, 0.0)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["to_truth"] = list(self.to_truth)
        return out


def check_frame(initial, truth_start, gate: float) -> FrameCheck:
    """The frame of a run started at ``initial`` (evaluation.InitialPose) against the ground
    truth's start ``truth_start`` (an InitialPose, or None when the bag has none)."""
    identity = (0.0, 0.0, 0.0)
    if initial.in_truth_frame:
        return FrameCheck(initial.source, True, identity, note="initial pose from the ground truth")
    if truth_start is None:
        return FrameCheck(initial.source, None, identity,
                          note=f"frames not checked: initial pose from {initial.source} and no ground-truth "
                               "start pose (GPS or /ground_truth/pose) to compare it with; the figures assume "
                               "the estimate's frame is the ground truth's (the shape error does not)")
    p, g = initial.pose, truth_start.pose
    offset = math.hypot(p[0] - g[0], p[1] - g[1])
    turn = math.degrees(math.atan2(math.sin(p[2] - g[2]), math.cos(p[2] - g[2])))
    common = dict(offset_m=offset, offset_deg=turn, truth_start_source=truth_start.source)
    if offset <= gate and abs(turn) <= SAME_FRAME_HEADING_DEG:
        return FrameCheck(initial.source, True, identity, **common,
                          note=f"initial pose from {initial.source}, {offset:.2f} m and {turn:.1f} deg from the "
                               "ground truth's start: taken as given in the ground-truth frame")
    to_truth = tuple(float(v) for v in compose(g, [inverse(p)])[0])
    return FrameCheck(initial.source, False, to_truth, **common,
                      note=f"the estimate's frame is not the ground truth's: its initial pose ({initial.source}) "
                           f"is {offset:.2f} m and {turn:.1f} deg from the ground truth's start; scored after "
                           "carrying the estimate into the ground-truth frame by the start poses")


def poses_to_truth(check: FrameCheck, poses) -> np.ndarray:
    """Poses (n, 3) of the estimate's frame in the ground-truth frame."""
    return compose(check.to_truth, poses)


def points_to_truth(check: FrameCheck, points) -> np.ndarray:
    """Points (n, 2) of the estimate's frame in the ground-truth frame."""
    xy = np.asarray(points, dtype=float).reshape(-1, 2)
    return compose(check.to_truth, np.column_stack([xy, np.zeros(len(xy))]))[:, :2]
