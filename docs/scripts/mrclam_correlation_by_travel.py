"""How alike two sightings' camera errors are, against how far the robot moved between them
(docs/RESULTS.md, "UTIAS MRCLAM", variant 49: the correlation the learner would need).

    python docs/scripts/mrclam_correlation_by_travel.py [--data-dir ../shared/datasets/mrclam] [--seconds 600]

Range and bearing errors against the Vicon poses and the survey (mrclam_sensor_truth.py), each
landmark's mean error removed and its errors beyond 5 MADs left out.  Every two consecutive
sightings of one landmark form a pair; pairs are binned by the robot's displacement between the
two (Vicon, m) and, separately, by the heading change (deg); each bin's correlation of the
pair's errors is printed per dataset (its five robots pooled), with the number of pairs.  The
online learner estimates one correlation per scan pair whatever the motion between them.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mrclam_sensor_truth import errors, mad
from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam
from online_em_slam.datasets.mrclam.survey import ground_truth_at

DISPLACEMENT_BINS = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, np.inf)
HEADING_BINS = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, np.inf)


def pairs(run) -> np.ndarray:
    """(n, 6), one row per two consecutive sightings of a landmark: range errors (previous, this),
    bearing errors (previous, this), the robot's displacement between them (m), its turn (deg)."""
    e_r, e_b = errors(run)
    x, y, yaw = ground_truth_at(run, run.measurement_times)
    rows = []
    for subject in np.unique(run.measurement_subjects):
        m = np.flatnonzero(run.measurement_subjects == subject)
        keep = ((np.abs(e_r[m] - np.median(e_r[m])) <= 5 * mad(e_r[m]) + 1e-12)
                & (np.abs(e_b[m] - np.median(e_b[m])) <= 5 * mad(e_b[m]) + 1e-12))
        m = m[keep]
        if m.size < 2:
            continue
        r, b = e_r[m] - e_r[m].mean(), e_b[m] - e_b[m].mean()
        moved = np.hypot(np.diff(x[m]), np.diff(y[m]))
        turned = np.degrees(np.abs(np.diff(yaw[m])))
        rows.append(np.column_stack([r[:-1], r[1:], b[:-1], b[1:], moved, turned]))
    return np.vstack(rows) if rows else np.zeros((0, 6))


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1]) if a.size > 2 else float("nan")


def table(all_pairs: np.ndarray, column: int, bins, unit: str) -> None:
    print(f"| {unit} | pairs | range | bearing |\n|---|---|---|---|")
    for low, high in zip(bins[:-1], bins[1:]):
        inside = all_pairs[(all_pairs[:, column] >= low) & (all_pairs[:, column] < high)]
        print(f"| {low:g}-{high:g} | {inside.shape[0]} | {correlation(inside[:, 0], inside[:, 1]):+.2f} | "
              f"{correlation(inside[:, 2], inside[:, 3]):+.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    args = parser.parse_args()
    for dataset in (1, 9):
        found = []
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), dataset), robot, args.seconds or None)
            p = pairs(run)
            # Each run standardised on its own: the robots' cameras differ in spread.
            p[:, :2] /= p[:, :2].std()
            p[:, 2:4] /= p[:, 2:4].std()
            found.append(p)
        pooled = np.vstack(found)
        print(f"\nDataset {dataset}: by the robot's displacement between the two sightings")
        table(pooled, 4, DISPLACEMENT_BINS, "displacement (m)")
        print(f"\nDataset {dataset}: by the heading change between them")
        table(pooled, 5, HEADING_BINS, "heading change (deg)")


if __name__ == "__main__":
    main()
