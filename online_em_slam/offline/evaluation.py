"""Accuracy and timing metrics of a SLAM run against ground truth (ROS-free, pure functions).

* :func:`landmark_metrics`: one-to-one matching of estimated to surveyed landmarks
  (Hungarian assignment on Euclidean distances, pairs farther than ``gate`` never
  match); RMSE over the matched pairs, true landmarks left unmatched (missed) and
  estimates left unmatched (spurious, including duplicates of a mapped landmark).
* :func:`landmark_metrics_by_id`: the same figures when the run was given the
  landmark ids (known association): each estimate is paired with the surveyed
  landmark of its id, and the RMSE, shape and frame cover every pair, however far
  (a landmark placed 5 m off counts 5 m, not as a missed one).
* :func:`map_error_split` / :func:`map_error`: landmark RMSE split into *shape*
  and *frame*, and the map's scale (:mod:`.map_fit`).
* :func:`trajectory_metrics`: position error of an estimated track against
  ground-truth positions.  The estimate is interpolated linearly at the
  ground-truth times (only inside the estimate's time span; ground-truth samples
  are never interpolated, so gaps in a GPS log are not bridged).  No alignment is
  applied by default: the error is measured in the ground-truth frame, in which
  the run was initialised (see :func:`initial_pose_from_gps`).  Optionally also
  reported after the best rigid 2-D alignment (rotation + translation, no scale;
  Kabsch / Umeyama), which removes the part of the error due to the initial pose.
* :func:`timing_metrics`: per-step processing time (mean, p99, max) and the
  real-time factor = dataset duration / wall time.

Plus the geometry helpers the runner needs: the sensor point of base poses
(:func:`sensor_points`) and the initial base pose from a GPS track that measures
the sensor point (:func:`initial_pose_from_gps`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

# The map fits live in map_fit; scripts and tests import them from here too.
from .map_fit import fitted_onto, map_error_split, map_scale_split, rigid_fit_2d, rotate_points  # noqa: F401

DEFAULT_MATCH_GATE = 2.0


def _finite_or_none(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _clean(data):
    """asdict() output with NaN/inf -> None and numpy scalars -> Python (JSON-safe)."""
    if isinstance(data, dict):
        return {k: _clean(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_clean(v) for v in data]
    if isinstance(data, (np.integer,)):
        return int(data)
    if isinstance(data, (float, np.floating)):
        return _finite_or_none(float(data))
    return data


# --------------------------------------------------------------------------- landmarks

@dataclass
class LandmarkMatch:
    true_index: int
    estimate_index: int
    estimate_id: int
    error: float


@dataclass
class LandmarkMetrics:
    """Result of :func:`landmark_metrics` (distances in metres)."""

    n_true: int
    n_estimated: int
    n_matched: int
    n_missed: int
    n_spurious: int
    rmse: float                   # over matched pairs (by id: every pair; nan when none)
    mean_error: float
    max_error: float
    gate: float
    shape_error: float = math.nan     # RMSE after the best rigid fit (see map_error_split)
    frame_error: float = math.nan     # sqrt(rmse^2 - shape_error^2)
    n_matched_fitted: int = 0     # within the gate after the best rigid fit (n_matched: truth's frame)
    map_scale: float = math.nan   # the map's size against the truth's (map_fit.map_scale_split)
    scaled_shape_error: float = math.nan    # RMSE after the best similarity fit
    matches: list[LandmarkMatch] = field(default_factory=list)
    missed: list[int] = field(default_factory=list)       # indices into the true landmarks
    spurious: list[int] = field(default_factory=list)     # ids of the unmatched estimates
    paired_by: str = "position"   # position (assignment within the gate) | id (known association)

    def to_dict(self) -> dict:
        return _clean(asdict(self))


def landmark_metrics(estimated, truth, gate: float = DEFAULT_MATCH_GATE, estimated_ids=None) -> LandmarkMetrics:
    """Match estimated landmark positions (M, 2) one-to-one to true positions (K, 2).

    The assignment minimises the summed distance over pairs closer than ``gate``
    (scipy ``linear_sum_assignment``); an estimate farther than ``gate`` from every
    true landmark, or losing its true landmark to a closer estimate, is spurious.
    ``estimated_ids`` (default 0..M-1) name the spurious estimates in the result.
    """
    est = np.asarray(estimated, dtype=float).reshape(-1, 2)
    tru = np.asarray(truth, dtype=float).reshape(-1, 2)
    ids = np.arange(len(est)) if estimated_ids is None else np.asarray(estimated_ids, dtype=int).reshape(-1)
    if len(ids) != len(est):
        raise ValueError(f"{len(ids)} ids for {len(est)} estimated landmarks")
    matches = _assigned(est, tru, ids, gate)
    matched_true = {m.true_index for m in matches}
    matched_est = {m.estimate_index for m in matches}
    errors = np.array([m.error for m in matches])
    e, t = est[[m.estimate_index for m in matches]], tru[[m.true_index for m in matches]]
    _, shape, frame = map_error_split(e, t)
    scale, scaled_shape = map_scale_split(e, t)
    fitted = _matched_after_fit(est, tru, matches, gate)
    return LandmarkMetrics(
        n_true=len(tru), n_estimated=len(est), n_matched=len(matches),
        n_missed=len(tru) - len(matches), n_spurious=len(est) - len(matches),
        rmse=float(np.sqrt(np.mean(errors ** 2))) if errors.size else math.nan,
        mean_error=float(errors.mean()) if errors.size else math.nan,
        max_error=float(errors.max()) if errors.size else math.nan,
        gate=float(gate), shape_error=float(shape), frame_error=float(frame), n_matched_fitted=fitted,
        map_scale=scale, scaled_shape_error=scaled_shape,
        matches=matches, missed=[i for i in range(len(tru)) if i not in matched_true],
        spurious=[int(ids[j]) for j in range(len(est)) if j not in matched_est])


def _assigned(est: np.ndarray, tru: np.ndarray, ids: np.ndarray, gate: float) -> list[LandmarkMatch]:
    """The one-to-one assignment of estimates (M, 2) to true landmarks (K, 2) of least summed
    distance over pairs within ``gate``, sorted by true landmark."""
    from scipy.optimize import linear_sum_assignment

    matches: list[LandmarkMatch] = []
    if len(est) and len(tru):
        dist = np.linalg.norm(tru[:, None, :] - est[None, :, :], axis=-1)       # (K, M)
        big = 1e6 * (1.0 + float(np.nanmax(np.where(np.isfinite(dist), dist, 0.0))))
        cost = np.where(np.isfinite(dist) & (dist <= gate), dist, big)
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols):
            if np.isfinite(dist[r, c]) and dist[r, c] <= gate:
                matches.append(LandmarkMatch(int(r), int(c), int(ids[c]), float(dist[r, c])))
    return sorted(matches, key=lambda m: m.true_index)


def _matched_after_fit(est: np.ndarray, tru: np.ndarray, matches: list[LandmarkMatch], gate: float) -> int:
    """Estimates (M, 2) matched to the truth (K, 2) within ``gate`` once moved by the matches' fit."""
    if len(matches) < 2:                       # one pair fixes no rotation
        return len(matches)
    moved = fitted_onto(est, est[[m.estimate_index for m in matches]], tru[[m.true_index for m in matches]])
    return len(_assigned(moved, tru, np.arange(len(est)), gate))


def landmark_metrics_by_id(estimated, estimated_ids, truth, truth_ids, gate: float = DEFAULT_MATCH_GATE
                           ) -> LandmarkMetrics:
    """Estimates (M, 2) with their ids (M,) against the surveyed landmarks (K, 2) with theirs (K,).

    Known association: estimate and surveyed landmark pair by id, so the error of
    every pair enters the RMSE, shape and frame.  ``matches`` (and ``n_matched``) are
    the pairs within ``gate``; a pair beyond it, or an estimate whose id is not
    surveyed, is spurious; a surveyed landmark without an estimate within the gate
    is missed.
    """
    est = np.asarray(estimated, dtype=float).reshape(-1, 2)
    ids = np.asarray(estimated_ids, dtype=int).reshape(-1)
    tru = np.asarray(truth, dtype=float).reshape(-1, 2)
    row_of = {int(i): k for k, i in enumerate(np.asarray(truth_ids, dtype=int).reshape(-1))}
    if len(ids) != len(est) or len(row_of) != len(tru):
        raise ValueError(f"{len(ids)} ids for {len(est)} estimates, {len(row_of)} distinct ids for {len(tru)} "
                         "surveyed landmarks")
    pairs = [(row_of[int(i)], j) for j, i in enumerate(ids) if int(i) in row_of and np.all(np.isfinite(est[j]))]
    errors = np.array([np.hypot(*(est[j] - tru[r])) for r, j in pairs])
    matches = sorted((LandmarkMatch(r, j, int(ids[j]), float(e)) for (r, j), e in zip(pairs, errors) if e <= gate),
                     key=lambda m: m.true_index)
    e, t = est[[j for _, j in pairs]], tru[[r for r, _ in pairs]]
    rmse, shape, frame = map_error_split(e, t)
    scale, scaled_shape = map_scale_split(e, t)
    fitted = int(np.sum(np.hypot(*(fitted_onto(e, e, t) - t).T) <= gate)) if len(pairs) >= 2 else len(pairs)
    matched_true, matched_est = {m.true_index for m in matches}, {m.estimate_index for m in matches}
    return LandmarkMetrics(
        n_true=len(tru), n_estimated=len(est), n_matched=len(matches), n_missed=len(tru) - len(matches),
        n_spurious=len(est) - len(matches), rmse=float(rmse),
        mean_error=float(errors.mean()) if errors.size else math.nan,
        max_error=float(errors.max()) if errors.size else math.nan,
        gate=float(gate), shape_error=float(shape), frame_error=float(frame), n_matched_fitted=fitted,
        map_scale=scale, scaled_shape_error=scaled_shape,
        matches=matches, missed=[i for i in range(len(tru)) if i not in matched_true],
        spurious=[int(ids[j]) for j in range(len(est)) if j not in matched_est], paired_by="id")


def landmark_pairs_by_id(ids, positions, truth) -> tuple[np.ndarray, np.ndarray]:
    """Estimated (n, 2) and true (n, 2) positions of the estimates whose id
    indexes the true landmarks (K, 2) (known association, as in simulation)."""
    ids = np.asarray(ids, dtype=int).reshape(-1)
    pos = np.asarray(positions, dtype=float).reshape(-1, 2)
    tru = np.asarray(truth, dtype=float).reshape(-1, 2)
    keep = (ids >= 0) & (ids < len(tru)) & np.all(np.isfinite(pos), axis=1)
    return pos[keep], tru[ids[keep]]


@dataclass
class MapError:
    """Result of :func:`map_error` (metres, degrees)."""

    n: int
    rmse: float
    shape_error: float
    frame_error: float
    rotation_deg: float        # the best rigid fit of the estimate onto the truth
    translation: list[float]

    def to_dict(self) -> dict:
        return _clean(asdict(self))


def map_error(estimated, truth) -> MapError:
    """:func:`map_error_split` of one map (n, 2) vs (n, 2), with the fitted motion."""
    e = np.asarray(estimated, dtype=float).reshape(-1, 2)
    t = np.asarray(truth, dtype=float).reshape(-1, 2)
    rmse, shape, frame = (float(v) for v in map_error_split(e, t))
    if len(e) == 0:
        return MapError(0, rmse, shape, frame, math.nan, [math.nan, math.nan])
    angle, c = rigid_fit_2d(e, t)
    return MapError(len(e), rmse, shape, frame, float(np.degrees(angle)), [float(c[0]), float(c[1])])


# --------------------------------------------------------------------------- geometry

def sensor_points(poses, offset) -> np.ndarray:
    """Position of the sensor mounted at ``offset`` = (x, y) in the base frame, for
    base poses (n, 3): p + R(yaw) offset."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    ox, oy = float(offset[0]), float(offset[1])
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.stack([poses[:, 0] + c * ox - s * oy, poses[:, 1] + s * ox + c * oy], axis=1)


def interpolate_positions(times, positions, query_times) -> np.ndarray:
    """Linear interpolation of positions (n, 2) at ``query_times``; NaN outside [t0, tn].

    ``times`` must be non-decreasing.  A query time equal to a sample time gives that sample.
    """
    t = np.asarray(times, dtype=float).reshape(-1)
    p = np.asarray(positions, dtype=float).reshape(len(t), -1)
    q = np.asarray(query_times, dtype=float).reshape(-1)
    out = np.full((len(q), p.shape[1]), np.nan)
    if len(t) == 0:
        return out
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be non-decreasing")
    inside = (q >= t[0]) & (q <= t[-1])
    for d in range(p.shape[1]):
        out[inside, d] = np.interp(q[inside], t, p[:, d])
    return out


def interpolate_poses(times, poses, query_times) -> np.ndarray:
    """Poses (n, 3) at ``query_times``: position linear, yaw along the shorter arc (unwrapped)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    unwrapped = poses.copy()
    unwrapped[:, 2] = np.unwrap(poses[:, 2]) if len(poses) else poses[:, 2]
    out = interpolate_positions(times, unwrapped, query_times)
    out[:, 2] = np.arctan2(np.sin(out[:, 2]), np.cos(out[:, 2]))
    return out


def rigid_alignment(source, target) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (2, 2) and translation t minimising sum |R source_i + t - target_i|^2
    (Kabsch / Umeyama without scale, det R = +1)."""
    src = np.asarray(source, dtype=float).reshape(-1, 2)
    dst = np.asarray(target, dtype=float).reshape(-1, 2)
    if len(src) < 2:
        t = (dst.mean(axis=0) - src.mean(axis=0)) if len(src) else np.zeros(2)
        return np.eye(2), t
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - mu_d).T @ (src - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    R = u @ np.diag([1.0, d]) @ vt
    return R, mu_d - R @ mu_s


# --------------------------------------------------------------------------- trajectory

@dataclass
class ErrorStats:
    n: int
    rmse: float
    mean: float
    median: float
    max: float

    @classmethod
    def of(cls, errors) -> "ErrorStats":
        e = np.asarray(errors, dtype=float)
        if e.size == 0:
            return cls(0, math.nan, math.nan, math.nan, math.nan)
        return cls(int(e.size), float(np.sqrt(np.mean(e ** 2))), float(e.mean()), float(np.median(e)),
                   float(e.max()))


@dataclass
class TrajectoryMetrics:
    """Position error (m) of the estimate interpolated at the ground-truth times."""

    alignment: str                   # "none": errors in the ground-truth frame as estimated
    n_ground_truth: int              # ground-truth samples given
    n_compared: int                  # of them inside the estimate's time span
    rmse: float
    mean: float
    median: float
    max: float
    final_error: float
    aligned: ErrorStats | None = None          # after the best rigid 2-D alignment (if requested)
    aligned_rotation_deg: float | None = None
    aligned_translation: list[float] | None = None

    def to_dict(self) -> dict:
        return _clean(asdict(self))


def trajectory_metrics(estimate_times, estimate_xy, truth_times, truth_xy, align: bool = False
                       ) -> TrajectoryMetrics:
    """Error of an estimated 2-D track against ground-truth positions.

    The estimate is interpolated at each ground-truth time inside its span;
    no alignment is applied to the reported errors.  With ``align`` the errors
    after the best rigid alignment of the estimate onto the truth are reported
    as well (``aligned``), with the rotation and translation used.
    """
    gt_t = np.asarray(truth_times, dtype=float).reshape(-1)
    gt = np.asarray(truth_xy, dtype=float).reshape(-1, 2)
    est = interpolate_positions(estimate_times, estimate_xy, gt_t)
    ok = np.all(np.isfinite(est), axis=1) & np.all(np.isfinite(gt), axis=1)
    est, gt_ok = est[ok], gt[ok]
    errors = np.linalg.norm(est - gt_ok, axis=1)
    stats = ErrorStats.of(errors)
    result = TrajectoryMetrics(alignment="none", n_ground_truth=len(gt_t), n_compared=stats.n,
                               rmse=stats.rmse, mean=stats.mean, median=stats.median, max=stats.max,
                               final_error=float(errors[-1]) if errors.size else math.nan)
    if align and len(est) >= 2:
        R, t = rigid_alignment(est, gt_ok)
        moved = est @ R.T + t
        result.aligned = ErrorStats.of(np.linalg.norm(moved - gt_ok, axis=1))
        result.aligned_rotation_deg = float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))
        result.aligned_translation = [float(t[0]), float(t[1])]
    return result


# --------------------------------------------------------------------------- timing

@dataclass
class TimingMetrics:
    n_steps: int
    mean_step_ms: float
    p99_step_ms: float
    max_step_ms: float
    total_step_s: float
    wall_time_s: float
    dataset_duration_s: float
    real_time_factor: float          # dataset duration / wall time (> 1: faster than real time)

    def to_dict(self) -> dict:
        return _clean(asdict(self))


def timing_metrics(step_durations, dataset_duration: float, wall_time: float) -> TimingMetrics:
    """Per-step durations (s) -> ms statistics; real-time factor = dataset_duration / wall_time."""
    ms = 1e3 * np.asarray(step_durations, dtype=float).reshape(-1)
    return TimingMetrics(
        n_steps=int(ms.size),
        mean_step_ms=float(ms.mean()) if ms.size else math.nan,
        p99_step_ms=float(np.percentile(ms, 99)) if ms.size else math.nan,
        max_step_ms=float(ms.max()) if ms.size else math.nan,
        total_step_s=float(ms.sum() / 1e3),
        wall_time_s=float(wall_time), dataset_duration_s=float(dataset_duration),
        real_time_factor=float(dataset_duration / wall_time) if wall_time > 0 else math.nan)


# --------------------------------------------------------------------------- initial pose

@dataclass
class InitialPose:
    x: float
    y: float
    yaw: float
    stamp: float
    source: str          # how it was obtained (for metrics.json)
    in_truth_frame: bool = False   # taken from the ground truth (GPS, /ground_truth/pose): its frame

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)

    def to_dict(self) -> dict:
        return _clean(asdict(self))


def initial_pose_from_gps(gps_times, gps_xy, sensor_offset, start_time: float,
                          odom_times=None, odom_poses=None, fit_distance: float = 10.0) -> InitialPose:
    """Base pose at ``start_time`` in the GPS frame, for a GPS that measures the sensor point.

    Position: the sensor point coincides with the first GPS fix (anchored there).
    Heading: with odometry (base poses in the odometry frame), the rotation that
    best aligns the odometry track of the sensor point with the GPS track over the
    first ``fit_distance`` metres driven, both taken relative to the first fix
    (the start of a run may be a turn, where the direction of the GPS track is not
    the heading); without odometry, the direction from the first fix to the first
    fix ``fit_distance`` metres away.  The pose is then carried from the first
    fix's time to ``start_time`` by the odometry (without: the pose at the fix).
    After this no alignment is applied to the run.
    """
    t = np.asarray(gps_times, dtype=float).reshape(-1)
    g = np.asarray(gps_xy, dtype=float).reshape(-1, 2)
    good = np.all(np.isfinite(g), axis=1) & np.isfinite(t)
    t, g = t[good], g[good]
    if len(t) < 2:
        raise ValueError("need at least two GPS fixes for the initial pose")
    offset = np.asarray(sensor_offset, dtype=float)[:2]
    dist = np.linalg.norm(g - g[0], axis=1)
    far = np.nonzero(dist >= fit_distance)[0]
    end = int(far[0]) if far.size else len(t) - 1
    if dist[end] < 0.5:
        raise ValueError("the GPS track does not move: no heading")
    if odom_times is not None and odom_poses is not None and len(odom_times) >= 2:
        ot = np.asarray(odom_times, dtype=float)
        op = np.asarray(odom_poses, dtype=float).reshape(-1, 3)
        sel = slice(0, end + 1)
        at = np.clip(t[sel], ot[0], ot[-1])
        odo = interpolate_poses(ot, op, at)
        odo_sensor = sensor_points(odo, offset)
        a = odo_sensor - odo_sensor[0]
        b = g[sel] - g[0]
        # Rotation about the first point minimising sum |R a_i - b_i|^2.
        rot = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])), float(np.sum(a * b)))
        start = interpolate_poses(ot, op, [min(max(start_time, ot[0]), ot[-1])])[0]
        c, s = math.cos(rot), math.sin(rot)
        R = np.array([[c, -s], [s, c]])
        start_sensor = sensor_points(start[None], offset)[0]
        sensor_map = g[0] + R @ (start_sensor - odo_sensor[0])
        yaw = start[2] + rot
        source = f"gps+odometry (first fix at {t[0]:.3f} s, heading fitted over {dist[end]:.1f} m)"
    else:
        yaw = math.atan2(g[end, 1] - g[0, 1], g[end, 0] - g[0, 0])
        sensor_map = g[0]
        source = f"gps (first fix at {t[0]:.3f} s, heading = track direction over {dist[end]:.1f} m)"
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    c, s = math.cos(yaw), math.sin(yaw)
    base = sensor_map - np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]])
    return InitialPose(float(base[0]), float(base[1]), float(yaw), float(start_time), source, in_truth_frame=True)
