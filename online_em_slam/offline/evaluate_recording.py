"""``online-em-slam evaluate OUTBAG --truth INBAG``: the metrics of ``run`` for a recorded node run.

    online-em-slam evaluate OUTBAG [--truth INBAG] [--params FILE] [--output DIR]
                            [--node-name NAME] [--node-initial-pose params|gps|X,Y,YAW]
                            [--match-gate M] [--align] [--no-plot]

OUTBAG is a bag recorded from the live node (``online-em-slam-record`` or
``ros2 bag record``): the trajectory is read from ``/NAME/pose`` and the map from
the last ``/NAME/landmarks`` cloud.  INBAG (default: OUTBAG itself) gives the
ground truth (``/ground_truth/position``, ``/ground_truth/landmarks``), the
odometry and the sensor mounting (``/tf_static`` base_link -> laser, when
``--params`` does not set ``sensor.offset_*``).  The metric functions are those of
``run`` (:mod:`online_em_slam.offline.evaluation`); landmarks count once confirmed
(``n_obs >= association.confirm_observations``).

Frames: the node's map frame is its start pose, the ground truth is in the GPS
frame.  ``--node-initial-pose`` says how the node was started: ``params``
(default, the params file's ``initial_pose.*``, (0, 0, 0) without), ``gps`` (at the
GPS-derived pose, as ``run`` and the demo do: map = GPS frame) or ``X,Y,YAW``.
The estimate is carried into the GPS frame by T(gps<-map) = G P^-1 with G the
start pose fitted to the first GPS metres (as ``run --initial-pose gps``) and P
the node's initial pose; no alignment otherwise (``--align`` adds the aligned error).

Outputs in DIR (default: OUTBAG_eval): ``metrics.json``, ``trajectory.csv``,
``landmarks.csv``, TUM files for evo (:mod:`online_em_slam.offline.tum`) and ``map.png``.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bag.bagio import absolute_topic
from .frames import compose, inverse
from .evaluation import (DEFAULT_MATCH_GATE, initial_pose_from_gps, landmark_metrics, sensor_points,
                         trajectory_metrics)
from ..messages.quaternion import quaternion_to_yaw

GT_POSITION_TOPIC = "/ground_truth/position"
GT_LANDMARKS_TOPIC = "/ground_truth/landmarks"


# --------------------------------------------------------------------------- reading

@dataclass
class Recorded:
    poses: np.ndarray                 # (n, 4) t, x, y, yaw in the node's map frame
    landmarks: dict | None            # columns of the last landmark cloud
    frame: str


def read_recorded(bag, pose_topic: str, landmarks_topic: str) -> Recorded:
    """The node's pose track and final map from a recorded bag."""
    from ..bag.bagio import read_bag
    from ..messages.cloud import decode_message

    rows, last_cloud, frame = [], None, ""
    for topic, stamp, msg in read_bag(bag, [pose_topic, landmarks_topic]):
        if topic == pose_topic:
            p = msg.pose.pose
            # Latched poses are re-delivered to late subscribers: keep strictly increasing stamps.
            if not rows or stamp > rows[-1][0]:
                rows.append((stamp, p.position.x, p.position.y, quaternion_to_yaw(p.orientation)))
            frame = msg.header.frame_id
        else:
            last_cloud = msg
    if not rows:
        raise ValueError(f"{bag}: no messages on {pose_topic}")
    cols = None
    if last_cloud is not None:
        cols = decode_message(last_cloud, required=("x", "y"))
    return Recorded(np.asarray(rows, dtype=float).reshape(-1, 4), cols, frame)


@dataclass
class Truth:
    gps_times: np.ndarray
    gps_xy: np.ndarray
    landmarks: np.ndarray | None
    odom_times: np.ndarray
    odom_poses: np.ndarray
    start: float | None               # first motion input stamp (the node's start)
    sensor_offset: tuple | None       # base_link -> laser from /tf_static


def read_truth(bag, settings) -> Truth:
    from ..bag.bagio import read_bag
    from ..messages.cloud import decode_message

    odom_topic, control_topic = absolute_topic(settings.odom_topic), absolute_topic(settings.control_topic)
    gps_t, gps, odom_t, odom, landmarks, offset, start = [], [], [], [], None, None, None
    topics = [GT_POSITION_TOPIC, GT_LANDMARKS_TOPIC, odom_topic, control_topic, "/tf_static"]
    for topic, stamp, msg in read_bag(bag, topics):
        if topic in (odom_topic, control_topic):
            start = stamp if start is None else min(start, stamp)
        if topic == GT_POSITION_TOPIC:
            gps_t.append(stamp)
            gps.append((msg.point.x, msg.point.y))
        elif topic == odom_topic:
            p = msg.pose.pose
            odom_t.append(stamp)
            odom.append((p.position.x, p.position.y, quaternion_to_yaw(p.orientation)))
        elif topic == GT_LANDMARKS_TOPIC and landmarks is None:
            cols = decode_message(msg, required=("x", "y"))
            landmarks = np.column_stack([cols["x"], cols["y"]]).astype(float)
        elif topic == "/tf_static":
            for t in msg.transforms:
                if t.child_frame_id == "laser":
                    offset = (t.transform.translation.x, t.transform.translation.y)
    return Truth(np.asarray(gps_t, dtype=float), np.asarray(gps, dtype=float).reshape(-1, 2), landmarks,
                 np.asarray(odom_t, dtype=float), np.asarray(odom, dtype=float).reshape(-1, 3), start, offset)


# --------------------------------------------------------------------------- frames

def map_in_truth_frame(mode: str, truth: Truth, node_initial, sensor_offset) -> tuple[float, float, float]:
    """T(truth <- node map) for the ``--node-initial-pose`` mode (see the module docstring)."""
    if mode == "gps":
        return (0.0, 0.0, 0.0)
    if mode != "params":
        from .runner import parse_pose
        node_initial = parse_pose(mode)
    if len(truth.gps_times) < 2:
        raise ValueError("the truth bag has no GPS track to place the node's map frame")
    odom = (truth.odom_times, truth.odom_poses) if len(truth.odom_times) >= 2 else (None, None)
    start = truth.start if truth.start is not None else float(truth.gps_times[0])
    g = initial_pose_from_gps(truth.gps_times, truth.gps_xy, sensor_offset, start, *odom)
    return tuple(float(v) for v in compose(g.pose, [inverse(node_initial)])[0])


# --------------------------------------------------------------------------- metrics

def confirmed_mask(cols: dict, confirm_observations: int) -> np.ndarray:
    if "confirmed" in cols:
        return np.asarray(cols["confirmed"]).astype(bool)
    if "n_obs" in cols:
        return np.asarray(cols["n_obs"]) >= confirm_observations
    return np.ones(len(cols["x"]), dtype=bool)


def evaluate_recorded(recorded: Recorded, truth: Truth, to_truth, sensor_offset, confirm_observations: int,
                      match_gate: float = DEFAULT_MATCH_GATE, align: bool = False) -> dict:
    """metrics.json content: the landmark and trajectory metrics of ``run``."""
    poses = compose(to_truth, recorded.poses[:, 1:4])
    metrics: dict = {"n_poses": int(len(poses)), "map_in_truth_frame": list(to_truth)}
    cols = recorded.landmarks
    if cols is not None:
        xy = compose(to_truth, np.column_stack([cols["x"], cols["y"], np.zeros(len(cols["x"]))]))[:, :2]
        confirmed = confirmed_mask(cols, confirm_observations)
        ids = np.asarray(cols["id"], dtype=int) if "id" in cols else np.arange(len(xy))
        metrics["n_landmarks"] = int(len(xy))
        metrics["n_confirmed_landmarks"] = int(np.count_nonzero(confirmed))
        if truth.landmarks is not None:
            lmm = landmark_metrics(xy[confirmed], truth.landmarks, gate=match_gate, estimated_ids=ids[confirmed])
            metrics["landmarks"] = lmm.to_dict()
            metrics["landmarks"]["evaluated"] = "confirmed (n_obs >= association.confirm_observations)"
    if len(truth.gps_times) >= 2:
        points = sensor_points(poses, sensor_offset)
        tm = trajectory_metrics(recorded.poses[:, 0], points, truth.gps_times, truth.gps_xy, align=align)
        metrics["trajectory"] = tm.to_dict()
        metrics["trajectory"]["compared_point"] = "sensor point (pose + R(yaw) sensor offset) vs GPS"
    return metrics


def summary_line(metrics: dict) -> str:
    fmt = lambda v: "n/a" if v is None else f"{v:.3f}"   # noqa: E731
    parts = ["evaluate:"]
    lm, tr = metrics.get("landmarks"), metrics.get("trajectory")
    if lm:
        split = (f" (shape {fmt(lm['shape_error'])}, frame {fmt(lm['frame_error'])})"
                 if "shape_error" in lm else "")
        parts.append(f"landmarks {lm['n_matched']}/{lm['n_true']} mapped, {lm['n_spurious']} spurious, "
                     f"RMSE {fmt(lm['rmse'])} m{split};")
    if tr:
        parts.append(f"trajectory RMSE {fmt(tr['rmse'])} m (median {fmt(tr['median'])}, max {fmt(tr['max'])});")
    parts.append(f"{metrics.get('n_landmarks', 0)} landmarks ({metrics.get('n_confirmed_landmarks', 0)} "
                 f"confirmed), {metrics['n_poses']} poses")
    return " ".join(parts)


# --------------------------------------------------------------------------- outputs and command

def write_landmarks(path, cols: dict, xy: np.ndarray) -> None:
    """landmarks.csv as ``run`` writes it (positions in the ground-truth frame)."""
    n = len(xy)
    get = lambda k, default: np.asarray(cols[k]) if k in cols else np.full(n, default)   # noqa: E731
    ids, n_obs = get("id", -1), get("n_obs", 0)
    cov = [get(k, np.nan) for k in ("cov_xx", "cov_xy", "cov_yy")]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(("id", "x", "y", "cov_xx", "cov_xy", "cov_yy", "n_obs"))
        for i in range(n):
            writer.writerow((int(ids[i]), f"{xy[i, 0]:.6f}", f"{xy[i, 1]:.6f}",
                             *(f"{c[i]:.9g}" for c in cov), int(n_obs[i])))


def write_outputs(output: Path, recorded: Recorded, truth: Truth, to_truth, sensor_offset, metrics: dict,
                  confirm_observations: int, plot: bool) -> None:
    from .plots import plot_map
    from .report import json_dump, write_trajectory
    from .tum import write_run_tum

    output.mkdir(parents=True, exist_ok=True)
    poses = compose(to_truth, recorded.poses[:, 1:4])
    trajectory = np.column_stack([recorded.poses[:, 0], poses])
    write_trajectory(output / "trajectory.csv", trajectory)
    write_run_tum(output, trajectory, sensor_offset, truth.gps_times, truth.gps_xy)
    json_dump(output / "metrics.json", metrics)
    cols = recorded.landmarks
    xy = np.zeros((0, 2))
    if cols is not None:
        xy = compose(to_truth, np.column_stack([cols["x"], cols["y"], np.zeros(len(cols["x"]))]))[:, :2]
        write_landmarks(output / "landmarks.csv", cols, xy)
    if plot:
        confirmed = confirmed_mask(cols, confirm_observations) if cols is not None else None
        plot_map(output / "map.png", f"recorded run: {output.name}", trajectory, xy,
                 cols.get("id") if cols is not None else None, confirmed, truth.landmarks, truth.gps_xy,
                 sensor_offset)


def cmd_evaluate(args) -> int:
    from ..parameters.yaml_file import config_from_params, load_params

    values = load_params(args.params) if args.params else {}
    config, settings = config_from_params(values)
    truth = read_truth(args.truth or args.bag, settings)
    node = "/" + args.node_name.strip("/")
    recorded = read_recorded(args.bag, args.pose_topic or f"{node}/pose",
                             args.landmarks_topic or f"{node}/landmarks")
    # The params file is the authority on the sensor mounting; the bag's TF otherwise.
    if any(k.startswith("sensor.offset_") for k in values) or truth.sensor_offset is None:
        offset = (config.sensor.offset_x, config.sensor.offset_y)
    else:
        offset = truth.sensor_offset
    to_truth = map_in_truth_frame(args.node_initial_pose, truth, settings.initial_pose, offset)
    confirm = config.association.confirm_observations
    metrics = {"source": "recorded node run", "bag": str(args.bag), "truth": str(args.truth or args.bag),
               "params": args.params, "node_initial_pose": args.node_initial_pose, "sensor_offset": list(offset)}
    metrics.update(evaluate_recorded(recorded, truth, to_truth, offset, confirm, args.match_gate, args.align))
    output = Path(args.output) if args.output else Path(f"{str(args.bag).rstrip('/')}_eval")
    write_outputs(output, recorded, truth, to_truth, offset, metrics, confirm, not args.no_plot)
    print(summary_line(metrics))
    print(f"wrote {output}/metrics.json, trajectory.csv, trajectory.tum, sensor_trajectory.tum"
          + (", ground_truth.tum" if len(truth.gps_times) else "") + ("" if args.no_plot else ", map.png"))
    return 0


def add_parser(sub) -> None:
    """The ``evaluate`` subcommand of ``online-em-slam`` (cli.py)."""
    p = sub.add_parser("evaluate", help="metrics of a recorded node run (online-em-slam-record) against ground truth")
    p.add_argument("bag", help="bag recorded from the node")
    p.add_argument("--truth", default=None, help="bag with the ground truth and odometry (default: BAG)")
    p.add_argument("--params", default=None, help="the node's parameter file (sensor offset, confirmation, "
                                                  "initial pose, topic names)")
    p.add_argument("--output", default=None, help="output directory (default: BAG_eval)")
    p.add_argument("--node-name", default="online_em_slam", help="the node's name (topic prefix)")
    p.add_argument("--pose-topic", default=None, help="default /NODE/pose")
    p.add_argument("--landmarks-topic", default=None, help="default /NODE/landmarks")
    p.add_argument("--node-initial-pose", default="params", metavar="params|gps|X,Y,YAW",
                   help="how the node was started (default params: initial_pose.* of --params, else 0,0,0)")
    p.add_argument("--match-gate", type=float, default=DEFAULT_MATCH_GATE, help="landmark matching gate (m)")
    p.add_argument("--align", action="store_true", help="also report the error after a rigid 2-D alignment")
    p.add_argument("--no-plot", action="store_true", help="do not write map.png")
    p.set_defaults(func=cmd_evaluate)
