"""The camera's range and bearing errors on MRCLAM, against the Vicon poses and the survey.

    python docs/scripts/mrclam_sensor_truth.py [--data-dir ../shared/datasets/mrclam] [--seconds 600]

Each kept measurement is compared with the range and bearing of its surveyed landmark
seen from the ground-truth pose interpolated at its time (the loader's survey, labels
corrected: datasets/mrclam/survey.py).  Prints per run: range error std, median absolute
deviation (x 1.4826) and mean; the same for bearing in degrees; the share of bearing errors
beyond 10 degrees; the lag-1 correlation of a landmark's consecutive errors (less than 1 s
apart, its mean error removed, beyond 5 MADs left out): the serial correlation the filter
would learn from exact poses.
"""
import argparse
from pathlib import Path

import numpy as np

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam
from online_em_slam.datasets.mrclam.survey import ground_truth_at


def mad(x):
    return 1.4826 * np.median(np.abs(x - np.median(x)))


def errors(run):
    x, y, yaw = ground_truth_at(run, run.measurement_times)
    survey = dict(zip(run.landmark_subjects.tolist(), run.landmark_xy))
    landmark = np.array([survey[s] for s in run.measurement_subjects.tolist()])
    expected_range = np.hypot(landmark[:, 0] - x, landmark[:, 1] - y)
    expected_bearing = np.arctan2(landmark[:, 1] - y, landmark[:, 0] - x) - yaw
    return (run.measurement_range - expected_range,
            np.angle(np.exp(1j * (run.measurement_bearing - expected_bearing))))


def serial_correlation(run, error):
    """Lag-1 correlation of each landmark's consecutive errors (< 1 s apart), its mean removed."""
    t, subjects, pairs = run.measurement_times, run.measurement_subjects, []
    for subject in np.unique(subjects):
        m = subjects == subject
        e, tt = error[m], t[m]
        keep = np.abs(e - np.median(e)) <= 5.0 * mad(e) + 1e-12
        e, tt = e[keep] - e[keep].mean(), tt[keep]
        close = np.diff(tt) < 1.0
        pairs += list(zip(e[:-1][close], e[1:][close]))
    a = np.array(pairs)
    return float(np.corrcoef(a.T)[0, 1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    args = parser.parse_args()
    print("run    n     range std / mad / mean (m)     bearing std / mad / mean (deg)   |b| > 10 deg"
          "   lag-1 corr range / bearing")
    for dataset in (1, 9):
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), dataset), robot, args.seconds or None)
            er, eb = errors(run)
            b = np.degrees(eb)
            print(f"D{dataset}R{robot} {len(er):5d}   {er.std():.3f} / {mad(er):.3f} / {er.mean():+.3f}"
                  f"          {b.std():5.2f} / {mad(b):.2f} / {b.mean():+.2f}           {np.mean(np.abs(b) > 10):.3f}"
                  f"        {serial_correlation(run, er):.2f} / {serial_correlation(run, eb):.2f}")


if __name__ == "__main__":
    main()
