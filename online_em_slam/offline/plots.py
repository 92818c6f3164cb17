"""Figures of a run (matplotlib, Agg backend: no display needed)."""
from __future__ import annotations

import numpy as np

from .evaluation import sensor_points


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
