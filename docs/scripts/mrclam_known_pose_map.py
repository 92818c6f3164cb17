"""MRCLAM landmarks mapped from the Vicon poses: what the camera alone allows, and a range bias.

    python docs/scripts/mrclam_known_pose_map.py [--data-dir ../shared/datasets/mrclam] \
        [--seconds 600] [--bias-prior 0.05]

Mapping with known poses (no SLAM): each landmark seen at least 20 times is placed by
least squares over its range-bearing measurements from the ground-truth poses interpolated
at their times (Gauss-Newton, Huber weights at 2 sigma, sigma_range 0.12 m, sigma_bearing
1 deg), and scored against the survey in the ground-truth frame and after the best rigid fit
(shape).  Then again with a per-landmark range bias b_k (range = |theta_k - p| + b_k, the
issue's "systematic per-landmark observation error") under a prior N(0, bias_prior^2):
does modelling the bias bring the map closer to the survey?  Last, whether the biases are the
landmark's (the same for every robot): each robot's per-landmark median range errors, its own
mean removed, correlated between the robots of a dataset.
"""
import argparse
from pathlib import Path

import numpy as np

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam
from online_em_slam.datasets.mrclam.survey import ground_truth_at
from online_em_slam.offline.evaluation import map_error

SIGMA_RANGE, SIGMA_BEARING = 0.12, np.radians(1.0)
MIN_MEASUREMENTS = 20


def place(pose, y, start, bias_prior=None):
    """Landmark (x, y) or (x, y, b) from poses (3, n) and measurements y (n, 2)."""
    x, yy, yaw = pose
    with_bias = bias_prior is not None
    z = np.r_[start, 0.0] if with_bias else np.array(start, dtype=float)
    for _ in range(30):
        dx, dy = z[0] - x, z[1] - yy
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        e_r = (y[:, 0] - r - (z[2] if with_bias else 0.0)) / SIGMA_RANGE
        e_b = np.angle(np.exp(1j * (y[:, 1] - np.arctan2(dy, dx) + yaw))) / SIGMA_BEARING
        w_r = np.minimum(1.0, 2.0 / np.maximum(np.abs(e_r), 1e-9))
        w_b = np.minimum(1.0, 2.0 / np.maximum(np.abs(e_b), 1e-9))
        extra = [np.ones_like(r)] if with_bias else []
        J_r = np.column_stack([dx / r, dy / r] + extra) / SIGMA_RANGE
        J_b = np.column_stack([-dy / q, dx / q] + [0.0 * r for _ in extra]) / SIGMA_BEARING
        A = (J_r * w_r[:, None]).T @ J_r + (J_b * w_b[:, None]).T @ J_b
        g = (J_r * w_r[:, None]).T @ e_r + (J_b * w_b[:, None]).T @ e_b
        if with_bias:
            A[2, 2] += 1.0 / bias_prior ** 2
            g[2] -= z[2] / bias_prior ** 2
        step = np.linalg.solve(A, g)
        z = z + step
        if np.abs(step).max() < 1e-7:
            break
    return z


def run_maps(run, bias_prior):
    x, y, yaw = ground_truth_at(run, run.measurement_times)
    survey = dict(zip(run.landmark_subjects.tolist(), run.landmark_xy))
    plain, biased, truth = [], [], []
    for subject in np.unique(run.measurement_subjects):
        m = run.measurement_subjects == subject
        if m.sum() < MIN_MEASUREMENTS:
            continue
        pose = np.stack([x[m], y[m], yaw[m]])
        meas = np.column_stack([run.measurement_range[m], run.measurement_bearing[m]])
        start = survey[int(subject)] + 0.1
        plain.append(place(pose, meas, start))
        biased.append(place(pose, meas, start, bias_prior)[:2])
        truth.append(survey[int(subject)])
    return map_error(np.array(plain), np.array(truth)), map_error(np.array(biased), np.array(truth))


def median_range_errors(run) -> dict[int, float]:
    """Each landmark's (seen at least MIN_MEASUREMENTS times) median range error against Vicon."""
    x, y, _ = ground_truth_at(run, run.measurement_times)
    survey = dict(zip(run.landmark_subjects.tolist(), run.landmark_xy))
    out = {}
    for subject in np.unique(run.measurement_subjects):
        m = run.measurement_subjects == subject
        if m.sum() >= MIN_MEASUREMENTS:
            lx, ly = survey[int(subject)]
            out[int(subject)] = float(np.median(run.measurement_range[m] - np.hypot(lx - x[m], ly - y[m])))
    return out


def between_robot_correlation(medians: list[dict[int, float]]) -> float:
    """Mean pairwise correlation of the robots' landmark biases over the landmarks all saw."""
    common = sorted(set.intersection(*(set(m) for m in medians)))
    B = np.array([[m[s] for s in common] for m in medians])
    C = np.corrcoef(B - B.mean(axis=1, keepdims=True))
    return float(C[np.triu_indices(len(medians), 1)].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--bias-prior", type=float, default=0.05)
    args = parser.parse_args()
    print("| run | landmarks | shape (m) | ground-truth frame (m) | with range bias: shape | frame |")
    print("|---|---|---|---|---|---|")
    shapes, correlation = [], {}
    for dataset in (1, 9):
        medians = []
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), dataset), robot, seconds=args.seconds)
            medians.append(median_range_errors(run))
            plain, biased = run_maps(run, args.bias_prior)
            shapes.append((plain.shape_error, biased.shape_error))
            print(f"| D{dataset} R{robot} | {plain.n} | {plain.shape_error:.3f} | {plain.rmse:.3f} | "
                  f"{biased.shape_error:.3f} | {biased.rmse:.3f} |")
        spread = np.mean([np.std(list(m.values())) for m in medians])
        correlation[dataset] = (between_robot_correlation(medians), spread)
    shapes = np.array(shapes)
    print(f"mean shape {shapes[:, 0].mean():.3f}; with the range bias {shapes[:, 1].mean():.3f} "
          f"(better on {(shapes[:, 1] < shapes[:, 0]).sum()} of {len(shapes)} runs)")
    for dataset, (corr, spread) in correlation.items():
        print(f"Dataset {dataset}: landmark median range errors spread {spread:.3f} m (std over landmarks, "
              f"mean over robots); between robots, own offsets removed, they correlate by {corr:+.2f}")


if __name__ == "__main__":
    main()
