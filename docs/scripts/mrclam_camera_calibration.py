"""MRCLAM: the camera's range and bearing calibration against Vicon, and the map's scale it sets.

Per run: the range fit measured = a true + b and the bearing fit error = offset + k true bearing
(errors against the Vicon pose and the survey, as mrclam_sensor_truth.py; ranges beyond 5 MADs left
out of the range fit, and bearings or ranges beyond 5 MADs out of the bearing fit),
and the scale of the map placed from the Vicon poses (mrclam_known_pose_map.py's least squares:
what the camera alone gives), by the best similarity fit onto the survey (map_fit.map_scale_split:
below 1 the map is smaller than the survey).

With ``--write OUT`` it writes a copy of Datasets 1 and 9 with every range corrected by its run's
fit, (r - b) / a, and with ``--bearings`` every bearing too, (bearing - offset) / (1 + k): oracles
of a known camera calibration, for the benchmark (``--data-dir OUT``; variant 71 of
docs/measurements/mrclam_600s_known_variants.md).

    python docs/scripts/mrclam_camera_calibration.py [--data-dir ../shared/datasets/mrclam] \\
        [--write OUT [--bearings]]
"""
from __future__ import annotations

import argparse
import tarfile
from pathlib import Path

import numpy as np

from mrclam_known_pose_map import MIN_MEASUREMENTS, place
from mrclam_sensor_truth import errors, mad
from online_em_slam.datasets.mrclam.dataset import load_mrclam
from online_em_slam.datasets.mrclam.survey import ground_truth_at
from online_em_slam.offline.map_fit import map_scale_split


def calibration(run) -> tuple[float, float, float, float]:
    """(a, b, offset, k) of the run's range and bearing fits against Vicon."""
    er, eb = errors(run)
    in_range = np.abs(er - np.median(er)) < 5 * mad(er)
    keep = in_range & (np.abs(eb - np.median(eb)) < 5 * mad(eb))
    true_range = (run.measurement_range - er)[in_range]
    (a, b), *_ = np.linalg.lstsq(np.column_stack([true_range, np.ones(in_range.sum())]),
                                 run.measurement_range[in_range], rcond=None)
    true_bearing = (run.measurement_bearing - eb)[keep]
    (offset, k), *_ = np.linalg.lstsq(np.column_stack([np.ones(keep.sum()), true_bearing]), eb[keep], rcond=None)
    return float(a), float(b), float(offset), float(k)


def known_pose_scale(run) -> float:
    """The scale of the map placed from the Vicon poses (landmarks seen at least MIN_MEASUREMENTS times)."""
    x, y, yaw = ground_truth_at(run, run.measurement_times)
    survey = dict(zip(run.landmark_subjects.tolist(), run.landmark_xy))
    placed, truth = [], []
    for subject in np.unique(run.measurement_subjects):
        m = run.measurement_subjects == subject
        if m.sum() >= MIN_MEASUREMENTS:
            measured = np.column_stack([run.measurement_range[m], run.measurement_bearing[m]])
            placed.append(place(np.stack([x[m], y[m], yaw[m]]), measured, survey[int(subject)] + 0.1))
            truth.append(survey[int(subject)])
    return map_scale_split(np.array(placed), np.array(truth))[0]


def corrected(text: str, fit: tuple[float, float, float, float], bearings: bool) -> str:
    """Measurement.dat text with the ranges (and the bearings) corrected by ``fit``."""
    a, b, offset, k = fit
    lines = []
    for line in text.splitlines():
        fields = line.split()
        if len(fields) == 4 and not line.lstrip().startswith("#"):
            t, subject, r, bearing = fields
            new_bearing = float((float(bearing) - offset) / (1.0 + k)) if bearings else float(bearing)
            line = f"{t}\t{subject}\t{float((float(r) - b) / a)!r}\t{new_bearing!r}"
        lines.append(line)
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--write", metavar="OUT", help="write the calibrated copy of the data here")
    parser.add_argument("--bearings", action="store_true", help="with --write: correct the bearings too")
    args = parser.parse_args()
    print("| run | range a | range b (m) | bearing offset (deg) | bearing k | known-pose map's scale |")
    print("|---|---|---|---|---|---|")
    for dataset in (1, 9):
        archive = Path(args.data_dir) / f"MRCLAM_Dataset{dataset}.tar.xz"
        if args.write:
            with tarfile.open(archive) as tar:
                tar.extractall(args.write, filter="data")
        for robot in range(1, 6):
            run = load_mrclam(archive, robot, seconds=args.seconds)
            fit = calibration(run)
            print(f"| D{dataset} R{robot} | {fit[0]:.4f} | {fit[1]:+.3f} | {np.degrees(fit[2]):+.2f} | {fit[3]:+.4f} | "
                  f"{known_pose_scale(run):.4f} |")
            if args.write:
                path = Path(args.write) / f"MRCLAM_Dataset{dataset}" / f"Robot{robot}_Measurement.dat"
                path.write_text(corrected(path.read_text(), fit, args.bearings))


if __name__ == "__main__":
    main()
