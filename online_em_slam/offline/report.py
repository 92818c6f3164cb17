"""Evaluation and report files of an offline run: metrics.json content, CSV outputs, summary and comparison tables.

Plots are in :mod:`online_em_slam.offline.plots`; the run itself in :mod:`online_em_slam.offline.runner`.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..core.config import SlamConfig
from .evaluation import (DEFAULT_MATCH_GATE, landmark_metrics, landmark_metrics_by_id, sensor_points, timing_metrics,
                         trajectory_metrics)
from .frames import FrameCheck, points_to_truth, poses_to_truth

TRAJECTORY_HEADER = ("t", "x", "y", "yaw")
LANDMARK_HEADER = ("id", "x", "y", "cov_xx", "cov_xy", "cov_yy", "n_obs")


def evaluate(result, inputs, config: SlamConfig, match_gate: float = DEFAULT_MATCH_GATE,
             align: bool = False, frame: FrameCheck | None = None) -> dict:
    """metrics.json content for a run (runner.RunResult on runner.BagInputs).

    ``frame`` (frames.check_frame): the estimate is scored after its motion into the
    ground-truth frame, and metrics.json's ``frame`` says which case the run was in.
    """
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
    if result.failures:
        metrics["input_failures"] = list(result.failures)
    positions = np.asarray(lm.positions).reshape(-1, 2)
    if frame is not None and (inputs.landmarks is not None or inputs.has_gps):
        metrics["frame"] = frame.to_dict()
    if frame is not None and frame.moved:
        positions = points_to_truth(frame, positions)
    if inputs.landmarks is not None:
        lmm = scored_landmarks(positions[confirmed], np.asarray(lm.ids)[confirmed], inputs,
                               match_gate, by_id=result.known_ids)
        metrics["landmarks"] = lmm.to_dict()
        metrics["landmarks"]["evaluated"] = "confirmed (n_obs >= association.confirm_observations)"
    if inputs.has_gps:
        for name, poses in (("trajectory", result.trajectory), ("trajectory_revised", result.revised)):
            if poses is not None and len(poses):
                metrics[name] = _trajectory_scores(poses, frame, inputs, config, align)
        if "trajectory_revised" in metrics:
            metrics["trajectory_revised"]["poses"] = "the last replay's, then as published"
    return metrics


def _trajectory_scores(traj: np.ndarray, frame: FrameCheck | None, inputs, config: SlamConfig, align: bool) -> dict:
    """trajectory_metrics of poses (n, 4) t, x, y, yaw, moved into the ground-truth frame as the map was."""
    if frame is not None and frame.moved:
        traj = np.column_stack([traj[:, 0], poses_to_truth(frame, traj[:, 1:4])])
    points = sensor_points(traj[:, 1:4], (config.sensor.offset_x, config.sensor.offset_y))
    scores = trajectory_metrics(traj[:, 0], points, inputs.gps_times, inputs.gps_xy, align=align).to_dict()
    scores["compared_point"] = "sensor point (pose + R(yaw) sensor offset) vs GPS"
    return scores


def scored_landmarks(positions, ids, inputs, match_gate: float, by_id: bool):
    """Landmark metrics of a map: paired by id when the run was given the ids (known association)
    and the survey names its landmarks, else by position within ``match_gate``."""
    if by_id and inputs.landmark_ids is not None:
        return landmark_metrics_by_id(positions, ids, inputs.landmarks, inputs.landmark_ids, match_gate)
    return landmark_metrics(positions, inputs.landmarks, gate=match_gate, estimated_ids=ids)


# --------------------------------------------------------------------------- files

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


def write_noise_params(path, learned_parameters: dict, file_values: dict, learned: dict) -> None:
    """DIR/noise.yaml: the run's parameter file with the noise it ended with (learned once warmed up).

    A parameter file a user passes back with ``--params`` (or to the node):
    the values of the file the run was given, the learned noise.* and motion.*
    standard deviations overlaid (the motion scale s folded in as sqrt(s)).
    """
    import yaml  # noqa: PLC0415
    values = dict(file_values)
    values.update(learned_parameters)
    tails = {"mixture": ("mixture_weights", "mixture_scales"), "student_t": ("dof",)}.get(learned["model"], ())
    shown = {k: learned[k] for k in ("model", "sigma_range", "sigma_bearing", "rho", "range_growth", *tails,
                                     "serial_correlation", "serial_length",
                                     "motion_scale", "observations", "motion_steps")}
    header = ("# Noise learned online by `online-em-slam run` (docs/METHOD.md, \"Noise learned online\").\n"
              "# The run's parameter file with the noise.* values and the motion noise stds it ended with\n"
              "# (learned ones once warmed up); pass it back with --params or to the node.\n"
              f"# learned: {json.dumps(shown)}\n")
    body = yaml.safe_dump({"/**": {"ros__parameters": values}}, sort_keys=False, default_flow_style=None, width=100)
    from ..core.mapping.mapfile import write_bytes_atomic  # noqa: PLC0415
    write_bytes_atomic(path, (header + body).encode())


def json_dump(path, data) -> None:
    # Atomic and fsynced, through an unpredictable temporary name: a predictable
    # "metrics.json.tmp" could be a planted symlink that sends the write elsewhere.
    from ..core.mapping.mapfile import write_bytes_atomic  # noqa: PLC0415
    write_bytes_atomic(path, (json.dumps(data, indent=2, sort_keys=False) + "\n").encode())


# --------------------------------------------------------------------------- summaries

def _scale(lm: dict) -> str:
    """", map scale S (shape without it X)" where the map's size is off by 0.5 % or more, else ""."""
    scale = lm.get("map_scale")
    if scale is None or not math.isfinite(scale) or abs(scale - 1.0) < 0.005:
        return ""
    return f", map scale {scale:.3f} (shape without it {_fmt(lm.get('scaled_shape_error'))})"


def summary_line(metrics: dict) -> str:
    parts = [f"{metrics['method']}:"]
    lm = metrics.get("landmarks")
    if lm:
        parts.append(f"landmarks {lm['n_matched']}/{lm['n_true']} mapped, {lm['n_spurious']} spurious, "
                     f"RMSE {_fmt(lm['rmse'])} m (shape {_fmt(lm.get('shape_error'))}, "
                     f"frame {_fmt(lm.get('frame_error'))}){_scale(lm)};")
    tr = metrics.get("trajectory")
    if tr:
        revised = metrics.get("trajectory_revised")
        again = f", {_fmt(revised['rmse'])} m as the replays filtered it again" if revised else ""
        parts.append(f"trajectory RMSE {_fmt(tr['rmse'])} m (median {_fmt(tr['median'])}, max {_fmt(tr['max'])}"
                     f"{again});")
    frame = metrics.get("frame")
    if frame and frame.get("same_frame") is False:
        parts.append(f"scored in the ground-truth frame after moving the estimate by its start pose "
                     f"({_fmt(frame['offset_m'], 1)} m, {_fmt(frame['offset_deg'], 1)} deg off);")
    elif frame and frame.get("same_frame") is None:
        parts.append("frames not checked (no ground-truth start pose);")
    tm = metrics["timing"]
    parts.append(f"{metrics['n_landmarks']} landmarks ({metrics['n_confirmed_landmarks']} confirmed); "
                 f"{_fmt(tm['mean_step_ms'], 2)} ms/step (p99 {_fmt(tm['p99_step_ms'], 2)}), "
                 f"real-time factor {_fmt(tm['real_time_factor'], 1)} (wall {_fmt(tm['wall_time_s'], 1)} s "
                 f"for {_fmt(tm['dataset_duration_s'], 1)} s)")
    return " ".join(parts)


def failure_warning(metrics: dict, who: str | None = None) -> str | None:
    """A line for stderr when inputs raised inside the estimator (each dropped, the estimate kept as
    before it): how many, and the first one's message.  ``who``: default the run's method."""
    count = metrics.get("runner_skipped", {}).get("internal_error", 0)
    if not count:
        return None
    first = metrics.get("input_failures", ["(message not kept)"])[0]
    return (f"warning: {count} input(s) failed inside {who or metrics['method']} and were dropped, the "
            f"estimate kept as before each; first: {first} (metrics.json: runner_skipped, input_failures)")


def _fmt(value, digits: int = 3) -> str:
    return "n/a" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.{digits}f}"


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


