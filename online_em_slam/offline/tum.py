"""TUM trajectory files (``timestamp x y z qx qy qz qw``, one pose a line) for ``evo``.

    evo_ape tum ground_truth.tum sensor_trajectory.tum --t_max_diff 0.05 --plot

``trajectory.tum`` is the base_link pose; ``sensor_trajectory.tum`` the sensor
(laser / GPS antenna) point with the base heading, which is what the GPS of the
KTH datasets measures; ``ground_truth.tum`` the GPS fixes (no heading: identity
orientation).  All in the ground-truth frame, z = 0.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .evaluation import sensor_points

TUM_FILES = ("trajectory.tum", "sensor_trajectory.tum", "ground_truth.tum")


def write_tum(path, times, poses) -> None:
    """``poses``: (n, 3) x, y, yaw, or (n, 2) x, y (written with identity orientation)."""
    t = np.asarray(times, dtype=float).reshape(-1)
    p = np.asarray(poses, dtype=float)
    p = p.reshape(len(t), -1) if p.size else np.zeros((len(t), 3))    # no poses: an empty file
    yaw = p[:, 2] if p.shape[1] >= 3 else np.zeros(len(t))
    rows = np.column_stack([t, p[:, 0], p[:, 1], np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t)),
                            np.sin(yaw / 2.0), np.cos(yaw / 2.0)])
    with open(path, "w") as handle:
        handle.write("# timestamp x y z qx qy qz qw\n")
        for row in rows:
            handle.write(f"{row[0]:.9f} " + " ".join(f"{v:.6f}" for v in row[1:4]) + " "
                         + " ".join(f"{v:.9f}" for v in row[4:]) + "\n")


def read_tum(path) -> np.ndarray:
    """(n, 8) array of a TUM file (comment lines skipped)."""
    return np.loadtxt(path, comments="#", ndmin=2).reshape(-1, 8)


def write_run_tum(output, trajectory, sensor_offset, gps_times=None, gps_xy=None) -> list[Path]:
    """The TUM files of a run: ``trajectory`` (n, 4) t, x, y, yaw in the ground-truth frame."""
    output = Path(output)
    traj = np.asarray(trajectory, dtype=float).reshape(-1, 4)
    written = [output / "trajectory.tum", output / "sensor_trajectory.tum"]
    write_tum(written[0], traj[:, 0], traj[:, 1:4])
    sensor = np.column_stack([sensor_points(traj[:, 1:4], sensor_offset), traj[:, 3]])
    write_tum(written[1], traj[:, 0], sensor)
    if gps_times is not None and len(gps_times):
        written.append(output / "ground_truth.tum")
        write_tum(written[2], gps_times, gps_xy)
    return written


def write_revised_tum(output, revised) -> None:
    """trajectory_revised.tum: the trajectory as the replays filtered it again (runner.revised_trajectory),
    when there is one."""
    if revised is not None:
        write_tum(Path(output) / "trajectory_revised.tum", revised[:, 0], revised[:, 1:4])
