"""MRCLAM: the speed the robots deliver falls with the commanded turn rate.

Over 1 s windows in which the robot was commanded to drive (at least 2 cm), the Vicon
displacement d is fitted by least squares as d = a c + b w, c the commanded distance and
w = sum |yaw rate| v dt the commanded distance weighted by the turn rate: delivered speed =
v (a + b |yaw rate|).  Prints a, b, b / a, the one gain of d on c alone, and the residual's
standard deviation under each fit.  The chord of a window's arc is within 1.5 % of the arc at
these turn rates, so the fall is not the geometry of the window.

With ``--write OUT`` it also writes a copy of Datasets 1 and 9 in which every commanded speed
is multiplied by max(0.1, 1 + k |yaw rate|), k the dataset's mean b / a: an oracle of a
learned turn-rate term, for the benchmark (``--data-dir OUT``; variant 70 of
docs/measurements/mrclam_600s_known_variants.md).

    python docs/scripts/mrclam_speed_in_turns.py [--data-dir ../shared/datasets/mrclam] [--write OUT]
"""
from __future__ import annotations

import argparse
import tarfile
from pathlib import Path

import numpy as np

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam

WINDOW = 1.0          # s
MIN_DRIVE = 0.02      # m commanded in a window for it to count


def windows(run) -> np.ndarray:
    """(3, W): commanded distance, turn-weighted commanded distance, Vicon displacement per window."""
    t, v, w = run.odometry_times, run.odometry_v, run.odometry_w
    gt, poses = run.ground_truth_times, run.ground_truth_poses
    dt = np.diff(t, append=t[-1])
    distance = np.concatenate([[0.0], np.cumsum(v * dt)])
    turning = np.concatenate([[0.0], np.cumsum(v * np.abs(w) * dt)])
    rows = []
    for a in np.arange(max(t[0], gt[0]) + 1.0, min(t[-1], gt[-1]) - WINDOW - 1.0, WINDOW):
        i0, i1 = np.searchsorted(gt, [a, a + WINDOW])
        j0, j1 = np.searchsorted(t, [a, a + WINDOW])
        c = distance[j1] - distance[j0]
        if c >= MIN_DRIVE:
            rows.append((c, turning[j1] - turning[j0], np.hypot(*(poses[i1, :2] - poses[i0, :2]))))
    return np.array(rows).T


def fit(c: np.ndarray, cw: np.ndarray, d: np.ndarray) -> tuple[float, float, float, float, float]:
    """(a, b, one gain, residual sd of the one gain, residual sd of a and b)."""
    A = np.column_stack([c, cw])
    (a, b), *_ = np.linalg.lstsq(A, d, rcond=None)
    g = float(np.sum(c * d) / np.sum(c * c))
    return float(a), float(b), g, float((d - g * c).std()), float((d - A @ [a, b]).std())


def write_oracle(source: Path, out: Path, k: dict[int, float]) -> None:
    for dataset in (1, 9):
        with tarfile.open(source / f"MRCLAM_Dataset{dataset}.tar.xz") as tar:
            tar.extractall(out, filter="data")
        for robot in range(1, 6):
            path = out / f"MRCLAM_Dataset{dataset}" / f"Robot{robot}_Odometry.dat"
            lines = []
            for line in path.read_text().splitlines():
                fields = line.split()
                if len(fields) == 3 and not line.lstrip().startswith("#"):
                    t, v, w = fields
                    line = f"{t}\t{float(v) * max(0.1, 1.0 + k[dataset] * abs(float(w)))!r}\t{w}"
                lines.append(line)
            path.write_text("\n".join(lines) + "\n")
        print(f"Dataset {dataset}: speeds times max(0.1, 1 {k[dataset]:+.2f} |yaw rate|) in {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--write", metavar="OUT", help="also write the oracle copy of the data here")
    args = parser.parse_args()
    print("| run | a | b (s/rad) | b / a | one gain | residual sd, one gain -> a, b (cm) |")
    print("|---|---|---|---|---|---|")
    ratios: dict[int, list[float]] = {1: [], 9: []}
    for dataset in (1, 9):
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), dataset), robot, seconds=args.seconds)
            a, b, g, sd_one, sd_two = fit(*windows(run))
            ratios[dataset].append(b / a)
            print(f"| D{dataset} R{robot} | {a:.3f} | {b:+.3f} | {b / a:+.2f} | {g:.3f} | "
                  f"{100 * sd_one:.2f} -> {100 * sd_two:.2f} |")
    if args.write:
        write_oracle(Path(args.data_dir), Path(args.write), {d: float(np.mean(r)) for d, r in ratios.items()})


if __name__ == "__main__":
    main()
