"""MRCLAM: the commanded yaw rate against Vicon, per run (the table in docs/RESULTS.md).

Vicon's orientation has glitches: steps of 0.9-3.1 rad within one 20 ms sample and back
(up to 175 in 600 s on Dataset 9). A yaw step faster than 4 rad/s (an iRobot Create turns at
most about 2 rad/s) is dropped; a 1 s window with more than a fifth of its steps dropped is
left out. Per run: the least-squares gain of the true yaw rate on the commanded one over
1 s windows, the residual's standard deviation and kurtosis (3 for a Gaussian), and the
gain of the windows turning in place (commanded speed below 1 cm/s) and while driving.

    python docs/scripts/mrclam_motion_truth.py [--data-dir ../shared/datasets/mrclam] [--seconds 600]

``--turns D R T0 T1 ...`` instead prints, for dataset D robot R, the turn commanded (the yaw
rate's integral) and made (Vicon's, glitches left out) between consecutive times T (s).
"""
import argparse
from pathlib import Path

import numpy as np

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam

MAX_RATE = 4.0      # rad/s: faster Vicon yaw steps are glitches
WINDOW = 1.0        # s


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def yaw_rate_windows(run, window=WINDOW):
    """(true, commanded) mean yaw rates over the windows with clean Vicon yaw."""
    t, w = run.odometry_times, run.odometry_w
    gt, yaw = run.ground_truth_times, run.ground_truth_poses[:, 2]
    rate = wrap(np.diff(yaw)) / np.diff(gt)
    good = np.abs(rate) < MAX_RATE
    mid = 0.5 * (gt[1:] + gt[:-1])
    true, cmd, speed = [], [], []
    for a in np.arange(max(t[0], gt[0]), min(t[-1], gt[-1]) - window, window):
        m = (mid >= a) & (mid < a + window)
        if m.sum() < 10 or good[m].mean() < 0.8:
            continue
        true.append(rate[m & good].mean())
        cmd.append(w[(t >= a) & (t < a + window)].mean())
        speed.append(run.odometry_v[(t >= a) & (t < a + window)].mean())
    return np.array(true), np.array(cmd), np.array(speed), int((~good).sum())


def gain_of(true, cmd):
    turning = np.abs(cmd) > 0.05
    if turning.sum() < 5:
        return "-"
    return f"{np.sum(true[turning] * cmd[turning]) / np.sum(cmd[turning] ** 2):.2f}"


def turns(run, times):
    """Rows (start, end, commanded turn, Vicon's turn) between consecutive ``times`` (s)."""
    t, w = run.odometry_times, run.odometry_w
    gt, yaw = run.ground_truth_times, run.ground_truth_poses[:, 2]
    step = wrap(np.diff(yaw))
    step[np.abs(step) / np.diff(gt) >= MAX_RATE] = 0.0
    made = np.concatenate([[0.0], np.cumsum(step)])
    turned = w * np.gradient(t)                     # the commanded turn of each odometry sample
    rows = []
    for a, b in zip(times[:-1], times[1:]):
        m = (t >= a) & (t < b)
        commanded = float(np.sum(turned[m]))
        rows.append((a, b, commanded, float(np.interp(b, gt, made) - np.interp(a, gt, made))))
    return rows


def print_turns(data_dir: Path, dataset: int, robot: int, times: list[float]) -> None:
    run = load_mrclam(dataset_source(data_dir, dataset), robot, seconds=max(times))
    print("| from (s) | to (s) | commanded (rad) | made (rad) | made / commanded |\n|---|---|---|---|---|")
    for a, b, commanded, made in turns(run, times):
        ratio = f"{made / commanded:.2f}" if abs(commanded) > 1e-3 else "-"
        print(f"| {a:g} | {b:g} | {commanded:.3f} | {made:.3f} | {ratio} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--turns", type=float, nargs="+", metavar="D R T",
                        help="dataset, robot and times (s): the turns made between the times")
    args = parser.parse_args()
    if args.turns:
        print_turns(Path(args.data_dir), int(args.turns[0]), int(args.turns[1]), args.turns[2:])
        return
    print("| run | yaw-rate gain | residual sd (rad/s) | kurtosis | Vicon yaw glitches | gain in place / driving |")
    print("|---|---|---|---|---|---|")
    for d in (1, 9):
        for r in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), d), r, seconds=args.seconds)
            true, cmd, speed, glitches = yaw_rate_windows(run)
            gain = float(np.sum(true * cmd) / np.sum(cmd * cmd))
            res = true - gain * cmd
            still = np.abs(speed) < 0.01
            print(f"| D{d} R{r} | {gain:.2f} | {res.std():.3f} | {np.mean((res / res.std()) ** 4):.1f} | {glitches} "
                  f"| {gain_of(true[still], cmd[still])} / {gain_of(true[~still], cmd[~still])} |")


if __name__ == "__main__":
    main()
