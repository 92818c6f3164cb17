"""Offline runner: a bag straight into an estimator (no DDS), deterministic for a seed.

    online-em-slam run BAG --params FILE --output DIR [--method online_em|ekf_slam|fastslam2|marginal_slam]
                       [--seed S] [--particles N] [--initial-pose auto|gps|params|X,Y,YAW]
                       [--match-gate M] [--align] [--no-plot]
    online-em-slam compare BAG --params FILE --output DIR [--methods ...] [--seed S] ...

``run`` reads the bag (rosbags, no rclpy) and feeds the estimator through the
node's own input path (:mod:`online_em_slam.pipeline`: stamp checks, the
(stamp, kind) ordered merge of the streams, the feeder), so the estimator sees
the identical sequence of inputs as the node: the control topic ->
``add_control`` (``motion_source: control``) or the odometry topic ->
``add_odometry`` (``motion_source: odom``), the observation topic (PointCloud2
with fields range, bearing and optional id, range_std, bearing_std) ->
``add_observations``.  Topic names and every setting come from the node's
parameter file (``--params``), read with :mod:`online_em_slam.paramfile`.
Empty observation clouds and observations before the first motion input are not
fed (counted under ``runner_skipped`` in metrics.json, with every input the path
refused, by reason).

Initial pose (``--initial-pose``, default ``auto``): the ``initial_pose.*`` keys
of the params file when it sets any; otherwise, when the bag has
``/ground_truth/position`` (a GPS measuring the sensor point, in the map frame),
from GPS: the sensor point at the first fix, the heading fitted to the first
10 m of GPS track (using /odom for the shape of the track when the bag has it;
see :func:`online_em_slam.evaluation.initial_pose_from_gps`); else (0, 0, 0).
No trajectory alignment is applied afterwards (``--align`` additionally reports
the error after a rigid alignment).

Outputs in DIR: ``trajectory.csv`` (t,x,y,yaw: the base pose after each
observation message), ``landmarks.csv`` (id,x,y,cov_xx,cov_xy,cov_yy,n_obs: the
whole map, as the node publishes it), ``metrics.json`` (timing, real-time factor,
map size, drops; landmark metrics against ``/ground_truth/landmarks`` and
trajectory metrics of the sensor point against ``/ground_truth/position`` when
the bag has them) and ``map.png``.  Landmark metrics count the landmarks seen at
least ``association.confirm_observations`` times (the confirmed ones).

``compare`` runs several methods on the same bag (DIR/<method>/ as ``run``) and
writes ``comparison.md`` and ``comparison.json``.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .cloud import decode_message
from .core.angles import wrap_angle
from .core.config import SlamConfig
from .core.types import Observations
from .evaluation import (DEFAULT_MATCH_GATE, InitialPose, initial_pose_from_gps, landmark_metrics,
                         sensor_points, timing_metrics, trajectory_metrics)
from .paramfile import config_from_params, load_params
from .pipeline import CONTROL, OBSERVATIONS, ODOMETRY, Feeder, InputPath
from .tum import write_run_tum

METHODS = ("online_em", "ekf_slam", "fastslam2", "marginal_slam")
GT_POSITION_TOPIC = "/ground_truth/position"
GT_LANDMARKS_TOPIC = "/ground_truth/landmarks"
TRAJECTORY_HEADER = ("t", "x", "y", "yaw")
LANDMARK_HEADER = ("id", "x", "y", "cov_xx", "cov_xy", "cov_yy", "n_obs")
ODOM = ODOMETRY


def _absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


# --------------------------------------------------------------------------- bag -> inputs

@dataclass
class BagInputs:
    """Everything a run needs from a bag, in log-time order (read once, reused by compare)."""

    path: str
    events: list                          # (kind, stamp, payload), kind as in online_em_slam.pipeline
    odom_times: np.ndarray
    odom_poses: np.ndarray
    gps_times: np.ndarray
    gps_xy: np.ndarray
    landmarks: np.ndarray | None          # (K, 2) surveyed landmarks
    landmark_ids: np.ndarray | None
    topics: dict = field(default_factory=dict)
    malformed: int = 0
    motion_source: str = "odom"           # which motion input drives the estimator (node setting)
    jump_threshold: float = 1.0           # node setting time_jump_threshold (stamp outliers)

    @property
    def has_gps(self) -> bool:
        return len(self.gps_times) >= 2


def observations_from_columns(columns: dict) -> Observations:
    """Core observations from decoded PointCloud2 columns (range, bearing [, id, range_std, bearing_std])."""
    ranges = np.asarray(columns["range"], dtype=float)
    bearings = np.asarray(columns["bearing"], dtype=float)
    finite = np.isfinite(bearings)
    bearings = np.where(finite, wrap_angle(np.where(finite, bearings, 0.0)), bearings)
    ids = columns.get("id")
    ids = np.full(ranges.shape, -1, dtype=np.int64) if ids is None else np.asarray(ids).astype(np.int64)
    std = {k: (np.asarray(columns[k], dtype=float) if k in columns else None) for k in ("range_std", "bearing_std")}
    return Observations(ranges, bearings, ids, std["range_std"], std["bearing_std"])


def read_inputs(bag, settings) -> BagInputs:
    """Read the motion, observation and ground-truth topics of ``bag`` (settings: NodeSettings)."""
    from .bagio import read_bag

    control_topic = _absolute(settings.control_topic)
    odom_topic = _absolute(settings.odom_topic)
    obs_topic = _absolute(settings.observations_topic)
    wanted = {obs_topic: OBSERVATIONS, odom_topic: ODOM}
    if settings.motion_source == "control":
        wanted[control_topic] = CONTROL
    topics = set(wanted) | {GT_POSITION_TOPIC, GT_LANDMARKS_TOPIC}
    events = []
    odom_t, odom_p, gps_t, gps_xy = [], [], [], []
    landmarks = landmark_ids = None
    malformed = 0
    counts: dict[str, int] = {}
    for topic, stamp, msg in read_bag(bag, topics):
        counts[topic] = counts.get(topic, 0) + 1
        kind = wanted.get(topic)
        if topic == odom_topic:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            pose = (float(p.x), float(p.y), _yaw(q))
            odom_t.append(stamp)
            odom_p.append(pose)
            if settings.motion_source == "odom":
                events.append((ODOM, stamp, pose))
        elif kind == CONTROL:
            events.append((CONTROL, stamp, (float(msg.twist.linear.x), float(msg.twist.angular.z))))
        elif kind == OBSERVATIONS:
            try:
                obs = observations_from_columns(decode_message(msg, required=("range", "bearing")))
            except ValueError:
                malformed += 1
                continue
            events.append((OBSERVATIONS, stamp, obs))
        elif topic == GT_POSITION_TOPIC:
            gps_t.append(stamp)
            gps_xy.append((float(msg.point.x), float(msg.point.y)))
        elif topic == GT_LANDMARKS_TOPIC and landmarks is None:
            cols = decode_message(msg, required=("x", "y"))
            landmarks = np.stack([cols["x"], cols["y"]], axis=1).astype(float)
            landmark_ids = (np.asarray(cols["id"], dtype=int) if "id" in cols else np.arange(len(landmarks)))
    return BagInputs(str(bag), events, np.asarray(odom_t, dtype=float), np.asarray(odom_p, dtype=float).reshape(-1, 3),
                     np.asarray(gps_t, dtype=float), np.asarray(gps_xy, dtype=float).reshape(-1, 2),
                     landmarks, landmark_ids, counts, malformed, settings.motion_source,
                     settings.time_jump_threshold)


# --------------------------------------------------------------------------- initial pose

def parse_pose(text: str) -> tuple[float, float, float]:
    parts = [float(v) for v in text.split(",")]
    if len(parts) != 3 or not all(math.isfinite(v) for v in parts):
        raise ValueError(f"expected X,Y,YAW, got {text!r}")
    return parts[0], parts[1], parts[2]


def choose_initial_pose(mode: str, inputs: BagInputs, config: SlamConfig, settings, file_values: dict
                        ) -> InitialPose:
    """See the module docstring (``--initial-pose``)."""
    start = inputs.events[0][1] if inputs.events else 0.0
    sets_pose = any(k.startswith("initial_pose.") for k in file_values)
    if mode == "auto":
        mode = "params" if sets_pose else ("gps" if inputs.has_gps else "params")
    if mode == "params":
        x, y, yaw = settings.initial_pose
        return InitialPose(x, y, yaw, start, "params file" if sets_pose else "default (0, 0, 0)")
    if mode == "gps":
        if not inputs.has_gps:
            raise ValueError(f"--initial-pose gps: the bag has no {GT_POSITION_TOPIC}")
        odom = (inputs.odom_times, inputs.odom_poses) if len(inputs.odom_times) >= 2 else (None, None)
        return initial_pose_from_gps(inputs.gps_times, inputs.gps_xy, (config.sensor.offset_x, config.sensor.offset_y),
                                     start, odom[0], odom[1])
    x, y, yaw = parse_pose(mode)
    return InitialPose(x, y, yaw, start, "command line")


# --------------------------------------------------------------------------- running

def make_estimator(method: str, config: SlamConfig, initial_pose):
    if method == "online_em":
        from .core import OnlineEMSlam
        return OnlineEMSlam(config, initial_pose=initial_pose)
    if method == "ekf_slam":
        from .baselines import EkfSlam
        return EkfSlam(config, initial_pose=initial_pose)
    if method == "fastslam2":
        from .baselines import FastSlam2
        return FastSlam2(config, initial_pose=initial_pose)
    if method == "marginal_slam":
        from .baselines import MarginalSlam
        return MarginalSlam(config, initial_pose=initial_pose)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


@dataclass
class RunResult:
    method: str
    trajectory: np.ndarray                # (n, 4): t, x, y, yaw
    landmarks: object                     # LandmarkMap
    durations: list
    wall_time: float
    dataset_duration: float
    drops: dict
    skipped: dict
    n_observation_messages: int


def motion_streams(motion_source: str) -> tuple[int, ...]:
    """The input streams that are merged: the motion input that drives the estimator and the observations."""
    return (ODOMETRY if motion_source == "odom" else CONTROL, OBSERVATIONS)


def feed(estimator, inputs: BagInputs) -> RunResult:
    """Feed the events through the node's input path; record the pose after every observation message.

    The bag stands for streams that never fall silent (no wall clock): the merge
    waits for every stream and the end of the bag releases the rest.
    """
    path = InputPath(motion_streams(inputs.motion_source), silence=math.inf,
                     jump_threshold=inputs.jump_threshold, restart_on_jump_back=False)
    feeder = Feeder(estimator, inputs.motion_source, path.drops)
    durations, rows = [], []
    n_obs_msgs = 0
    started = time.perf_counter()
    for kind, stamp, payload in inputs.events:
        n_obs_msgs += kind == OBSERVATIONS
        for item in path.push(kind, stamp, payload, 0.0).released:
            _feed_one(feeder, item, durations, rows)
    for item in path.flush():
        _feed_one(feeder, item, durations, rows)
    wall = time.perf_counter() - started
    stamps = [stamp for _, stamp, _ in inputs.events]
    skipped = {k: int(v) for k, v in path.drops.items() if v}
    if inputs.malformed:
        skipped["malformed_cloud"] = inputs.malformed
    return RunResult("", np.asarray(rows, dtype=float).reshape(-1, 4), estimator.landmarks(), durations, wall,
                     (max(stamps) - min(stamps)) if stamps else 0.0, dict(estimator.drops), skipped, n_obs_msgs)


def _feed_one(feeder: Feeder, item, durations: list, rows: list) -> None:
    fed = feeder.apply(item)
    if fed.report is not None:
        durations.append(fed.report.duration)
    if fed.trajectory_point is not None:
        rows.append(fed.trajectory_point)


def evaluate(result: RunResult, inputs: BagInputs, config: SlamConfig, match_gate: float = DEFAULT_MATCH_GATE,
             align: bool = False) -> dict:
    """metrics.json content for a run."""
    lm = result.landmarks
    confirmed = np.asarray(lm.n_obs) >= config.association.confirm_observations
    metrics: dict = {
        "n_landmarks": int(len(lm)),
        "n_confirmed_landmarks": int(np.count_nonzero(confirmed)),
        "n_observation_messages": result.n_observation_messages,
        "timing": timing_metrics(result.durations, result.dataset_duration, result.wall_time).to_dict(),
        "drops": {k: int(v) for k, v in sorted(result.drops.items())},
        "runner_skipped": result.skipped,
    }
    if inputs.landmarks is not None:
        lmm = landmark_metrics(np.asarray(lm.positions)[confirmed], inputs.landmarks, gate=match_gate,
                               estimated_ids=np.asarray(lm.ids)[confirmed])
        metrics["landmarks"] = lmm.to_dict()
        metrics["landmarks"]["evaluated"] = "confirmed (n_obs >= association.confirm_observations)"
    if inputs.has_gps and len(result.trajectory):
        traj = result.trajectory
        points = sensor_points(traj[:, 1:4], (config.sensor.offset_x, config.sensor.offset_y))
        tm = trajectory_metrics(traj[:, 0], points, inputs.gps_times, inputs.gps_xy, align=align)
        metrics["trajectory"] = tm.to_dict()
        metrics["trajectory"]["compared_point"] = "sensor point (pose + R(yaw) sensor offset) vs GPS"
    return metrics


# --------------------------------------------------------------------------- outputs

def write_trajectory(path, trajectory: np.ndarray) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(TRAJECTORY_HEADER)
        for t, x, y, yaw in trajectory:
            writer.writerow((f"{t:.9f}", f"{x:.6f}", f"{y:.6f}", f"{yaw:.8f}"))


def write_landmarks(path, landmarks) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(LANDMARK_HEADER)
        pos = np.asarray(landmarks.positions, dtype=float).reshape(-1, 2)
        cov = np.asarray(landmarks.covariances, dtype=float).reshape(-1, 2, 2)
        for i in range(len(pos)):
            writer.writerow((int(landmarks.ids[i]), f"{pos[i, 0]:.6f}", f"{pos[i, 1]:.6f}",
                             f"{cov[i, 0, 0]:.9g}", f"{cov[i, 0, 1]:.9g}", f"{cov[i, 1, 1]:.9g}",
                             int(landmarks.n_obs[i])))


def read_trajectory(path) -> np.ndarray:
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return data.reshape(-1, 4)


def plot_map(path, title: str, trajectory=None, landmarks_xy=None, landmark_ids=None, confirmed=None,
             gt_landmarks=None, gps_xy=None, sensor_offset=(0.0, 0.0)) -> None:
    """map.png: estimated landmarks (ids) and sensor-point track over ground truth (matplotlib Agg)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 8))
    if gps_xy is not None and len(gps_xy):
        ax.plot(gps_xy[:, 0], gps_xy[:, 1], ".", ms=2, color="0.6", label="GPS (ground truth)")
    if gt_landmarks is not None and len(gt_landmarks):
        ax.plot(gt_landmarks[:, 0], gt_landmarks[:, 1], "o", ms=10, mfc="none", mec="green",
                label="surveyed landmarks")
    if trajectory is not None and len(trajectory):
        pts = sensor_points(trajectory[:, 1:4], sensor_offset)
        ax.plot(pts[:, 0], pts[:, 1], "-", lw=1.0, color="tab:blue", label="estimate (sensor point)")
    if landmarks_xy is not None and len(landmarks_xy):
        conf = np.ones(len(landmarks_xy), dtype=bool) if confirmed is None else np.asarray(confirmed, dtype=bool)
        ax.plot(landmarks_xy[conf, 0], landmarks_xy[conf, 1], "x", color="red", ms=6, label="estimated landmarks")
        if (~conf).any():
            ax.plot(landmarks_xy[~conf, 0], landmarks_xy[~conf, 1], "x", color="orange", ms=4, alpha=0.6,
                    label="tentative")
        if landmark_ids is not None and len(landmarks_xy) <= 80:
            for (x, y), i in zip(landmarks_xy, landmark_ids):
                ax.annotate(str(int(i)), (x, y), textcoords="offset points", xytext=(3, 3), fontsize=7)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def json_dump(path, data) -> None:
    # Atomic and fsynced, through an unpredictable temporary name: a predictable
    # "metrics.json.tmp" could be a planted symlink that sends the write elsewhere.
    from .core.mapfile import write_bytes_atomic  # noqa: PLC0415
    write_bytes_atomic(path, (json.dumps(data, indent=2, sort_keys=False) + "\n").encode())


# --------------------------------------------------------------------------- commands

def run_one(inputs: BagInputs, config: SlamConfig, settings, method: str, initial: InitialPose, output: Path,
            plot: bool = True, match_gate: float = DEFAULT_MATCH_GATE, align: bool = False,
            extra: dict | None = None) -> dict:
    output.mkdir(parents=True, exist_ok=True)
    estimator = make_estimator(method, config, initial.pose)
    result = feed(estimator, inputs)
    result.method = method
    metrics = {"method": method, "bag": inputs.path, **(extra or {}),
               "seed": config.filter.seed, "num_particles": config.filter.num_particles,
               "motion_model": config.motion.model, "initial_pose": initial.to_dict()}
    metrics.update(evaluate(result, inputs, config, match_gate, align))
    write_trajectory(output / "trajectory.csv", result.trajectory)
    write_run_tum(output, result.trajectory, (config.sensor.offset_x, config.sensor.offset_y),
                  inputs.gps_times, inputs.gps_xy)       # TUM files for evo (tum.py)
    write_landmarks(output / "landmarks.csv", result.landmarks)
    json_dump(output / "metrics.json", metrics)
    if plot:
        lm = result.landmarks
        plot_map(output / "map.png", f"{method}: {Path(inputs.path).name}", result.trajectory,
                 np.asarray(lm.positions).reshape(-1, 2), lm.ids,
                 np.asarray(lm.n_obs) >= config.association.confirm_observations,
                 inputs.landmarks, inputs.gps_xy, (config.sensor.offset_x, config.sensor.offset_y))
    return metrics


def prepare(args) -> tuple:
    """(config, settings, file values, inputs, initial pose) from the common arguments."""
    file_values = load_params(args.params)
    overrides = {}
    if args.seed is not None:
        overrides["filter.seed"] = int(args.seed)
    if args.particles is not None:
        overrides["filter.num_particles"] = int(args.particles)
    config, settings = config_from_params(file_values, overrides)
    inputs = read_inputs(args.bag, settings)
    if not inputs.events:
        raise ValueError(f"{args.bag}: no inputs on the configured topics "
                         f"({settings.control_topic if settings.motion_source == 'control' else settings.odom_topic}, "
                         f"{settings.observations_topic})")
    initial = choose_initial_pose(args.initial_pose, inputs, config, settings, file_values)
    return config, settings, file_values, inputs, initial


def summary_line(metrics: dict) -> str:
    parts = [f"{metrics['method']}:"]
    lm = metrics.get("landmarks")
    if lm:
        parts.append(f"landmarks {lm['n_matched']}/{lm['n_true']} mapped, {lm['n_spurious']} spurious, "
                     f"RMSE {_fmt(lm['rmse'])} m (shape {_fmt(lm.get('shape_error'))}, "
                     f"frame {_fmt(lm.get('frame_error'))});")
    tr = metrics.get("trajectory")
    if tr:
        parts.append(f"trajectory RMSE {_fmt(tr['rmse'])} m (median {_fmt(tr['median'])}, max {_fmt(tr['max'])});")
    tm = metrics["timing"]
    parts.append(f"{metrics['n_landmarks']} landmarks ({metrics['n_confirmed_landmarks']} confirmed); "
                 f"{_fmt(tm['mean_step_ms'], 2)} ms/step (p99 {_fmt(tm['p99_step_ms'], 2)}), "
                 f"real-time factor {_fmt(tm['real_time_factor'], 1)} (wall {_fmt(tm['wall_time_s'], 1)} s "
                 f"for {_fmt(tm['dataset_duration_s'], 1)} s)")
    return " ".join(parts)


def _fmt(value, digits: int = 3) -> str:
    return "n/a" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.{digits}f}"


def cmd_run(args) -> int:
    config, settings, _, inputs, initial = prepare(args)
    metrics = run_one(inputs, config, settings, args.method, initial, Path(args.output), plot=not args.no_plot,
                      match_gate=args.match_gate, align=args.align, extra={"params": str(args.params)})
    print(summary_line(metrics))
    print(f"wrote {args.output}/trajectory.csv, landmarks.csv, metrics.json" + ("" if args.no_plot else ", map.png"))
    return 0


COMPARISON_COLUMNS = ("method", "beacons mapped", "spurious", "beacon RMSE (m)", "shape (m)", "frame (m)",
                      "trajectory RMSE (m)", "mean ms/step", "real-time factor")


def comparison_row(metrics: dict) -> dict:
    lm, tr, tm = metrics.get("landmarks"), metrics.get("trajectory"), metrics["timing"]
    return {
        "method": metrics["method"],
        "beacons_mapped": None if lm is None else lm["n_matched"],
        "beacons_true": None if lm is None else lm["n_true"],
        "spurious": None if lm is None else lm["n_spurious"],
        "beacon_rmse_m": None if lm is None else lm["rmse"],
        "beacon_shape_error_m": None if lm is None else lm.get("shape_error"),
        "beacon_frame_error_m": None if lm is None else lm.get("frame_error"),
        "trajectory_rmse_m": None if tr is None else tr["rmse"],
        "trajectory_median_m": None if tr is None else tr["median"],
        "n_landmarks": metrics["n_landmarks"],
        "n_confirmed_landmarks": metrics["n_confirmed_landmarks"],
        "mean_ms_per_step": tm["mean_step_ms"],
        "p99_ms_per_step": tm["p99_step_ms"],
        "real_time_factor": tm["real_time_factor"],
    }


def comparison_markdown(rows: list[dict], bag: str, params: str, seed, particles) -> str:
    lines = [f"# Method comparison on `{Path(bag).name}`", "",
             f"Params `{params}`, seed {seed}, {particles} particles (particle methods); "
             "landmark metrics over confirmed landmarks, one-to-one matching within the match gate "
             "(shape: RMSE after the best rigid 2-D fit onto the truth; frame = sqrt(RMSE^2 - shape^2)); "
             "trajectory error of the sensor point against GPS, no alignment.", "",
             "| " + " | ".join(COMPARISON_COLUMNS) + " |", "|" + "---|" * len(COMPARISON_COLUMNS)]
    for r in rows:
        mapped = "n/a" if r["beacons_mapped"] is None else f"{r['beacons_mapped']}/{r['beacons_true']}"
        spurious = "n/a" if r["spurious"] is None else str(r["spurious"])
        lines.append(f"| {r['method']} | {mapped} | {spurious} | {_fmt(r['beacon_rmse_m'])} | "
                     f"{_fmt(r['beacon_shape_error_m'])} | {_fmt(r['beacon_frame_error_m'])} | "
                     f"{_fmt(r['trajectory_rmse_m'])} | {_fmt(r['mean_ms_per_step'], 2)} | "
                     f"{_fmt(r['real_time_factor'], 1)} |")
    return "\n".join(lines) + "\n"


def cmd_compare(args) -> int:
    config, settings, _, inputs, initial = prepare(args)
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    rows = []
    for method in args.methods:
        cfg = SlamConfig.from_dict(config.to_dict())      # fresh copy per method
        metrics = run_one(inputs, cfg, settings, method, initial, output / method, plot=not args.no_plot,
                          match_gate=args.match_gate, align=args.align, extra={"params": str(args.params)})
        print(summary_line(metrics), flush=True)
        rows.append(comparison_row(metrics))
    json_dump(output / "comparison.json", {"bag": str(args.bag), "params": str(args.params),
                                           "seed": config.filter.seed, "num_particles": config.filter.num_particles,
                                           "initial_pose": initial.to_dict(), "methods": rows})
    (output / "comparison.md").write_text(comparison_markdown(rows, args.bag, args.params, config.filter.seed,
                                                              config.filter.num_particles))
    print((output / "comparison.md").read_text())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="online-em-slam",
                                     description="Offline SLAM runs on ROS 2 bags (no DDS) and their evaluation.")
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("bag", help="ROS 2 bag directory (mcap or sqlite3)")
        p.add_argument("--params", required=True, help="node parameter file (ROS 2 params YAML)")
        p.add_argument("--output", required=True, help="output directory")
        p.add_argument("--seed", type=int, default=None, help="random seed (overrides filter.seed)")
        p.add_argument("--particles", type=int, default=None, help="number of particles (overrides filter.num_particles)")
        p.add_argument("--initial-pose", default="auto", metavar="auto|gps|params|X,Y,YAW",
                       help="initial base pose (default auto: params file if it sets initial_pose.*, else GPS)")
        p.add_argument("--match-gate", type=float, default=DEFAULT_MATCH_GATE,
                       help="landmark matching gate (m) for the metrics")
        p.add_argument("--align", action="store_true",
                       help="also report the trajectory error after a rigid 2-D alignment")
        p.add_argument("--no-plot", action="store_true", help="do not write map.png")

    run = sub.add_parser("run", help="run one method on a bag")
    common(run)
    run.add_argument("--method", choices=METHODS, default="online_em")
    run.set_defaults(func=cmd_run)
    compare = sub.add_parser("compare", help="run several methods on a bag and tabulate them")
    common(compare)
    compare.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    compare.set_defaults(func=cmd_compare)
    from .evaluate_bag import add_parser as add_evaluate     # recorded node runs: evaluate_bag.py
    add_evaluate(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as error:
        print(f"online-em-slam: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
