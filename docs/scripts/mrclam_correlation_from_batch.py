"""The correlation-by-travel table of mrclam_correlation_by_travel.py, from the robot's own data:
the residuals of a batch solution instead of Vicon (docs/RESULTS.md, variant 54).  Can an
estimator that has no ground truth see how the camera's errors decay with the viewpoint?

    python docs/scripts/mrclam_correlation_from_batch.py BAG BATCH_RUN_DIR [BAG BATCH_RUN_DIR ...] \
        --params config/mrclam.yaml

BATCH_RUN_DIR: an ``online-em-slam run BAG --method batch --output DIR`` (its trajectory.csv holds
one pose per kept scan, its landmarks.csv the map).  Each kept observation's residual y - h(pose,
landmark) at that solution, each landmark's mean residual removed; pairs of a landmark's
consecutive sightings binned by the viewpoint's change between them (the batch poses' travel, and
their turn) as in the Vicon table; the correlation per bin, all the bags pooled.  Residuals at an
optimum are fitted ones (the solution moved towards them), so the correlations read low.
"""
from __future__ import annotations

import argparse
import csv
import types

import numpy as np

from mrclam_correlation_by_travel import DISPLACEMENT_BINS, HEADING_BINS, table
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.offline.batch import collect_problem, released_events
from online_em_slam.offline.cli import read_parameters
from online_em_slam.offline.runner import read_inputs


def residual_pairs(bag: str, run_dir: str, params: list[str]) -> np.ndarray:
    """(n, 6) as mrclam_correlation_by_travel.pairs: range (previous, this), bearing (previous, this),
    travel (m), turn (deg), from the batch solution in ``run_dir``."""
    config, settings, _ = read_parameters(types.SimpleNamespace(params=params, seed=0, particles=None))
    inputs = read_inputs(bag, settings)
    problem = collect_problem(released_events(inputs), config, inputs.motion_source)
    rows = np.array([[float(v) for v in row] for row in csv.reader(open(f"{run_dir}/trajectory.csv"))
                     if row and row[0] != "t"])
    marks = {int(r["id"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(open(f"{run_dir}/landmarks.csv"))}
    at = np.clip(np.searchsorted(rows[:, 0], problem.stamps[problem.obs_pose] - 1e-6), 0, len(rows) - 1)
    pose = rows[at, 1:4]
    theta = np.array([marks[int(i)] for i in problem.obs_id])
    dx, dy = theta[:, 0] - pose[:, 0], theta[:, 1] - pose[:, 1]
    e_r = problem.obs_y[:, 0] - np.hypot(dx, dy)
    e_b = wrap_angle(problem.obs_y[:, 1] - (np.arctan2(dy, dx) - pose[:, 2]))
    out = []
    for landmark in np.unique(problem.obs_id):
        m = np.flatnonzero(problem.obs_id == landmark)
        if m.size < 2:
            continue
        r, b = e_r[m] - e_r[m].mean(), e_b[m] - e_b[m].mean()
        travel = np.hypot(np.diff(pose[m, 0]), np.diff(pose[m, 1]))
        turn = np.degrees(np.abs(wrap_angle(np.diff(pose[m, 2]))))
        out.append(np.column_stack([r[:-1], r[1:], b[:-1], b[1:], travel, turn]))
    p = np.vstack(out)
    p[:, :2] /= p[:, :2].std()
    p[:, 2:4] /= p[:, 2:4].std()
    return p


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="+", help="BAG BATCH_RUN_DIR, repeated")
    parser.add_argument("--params", action="append", required=True)
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give BAG BATCH_RUN_DIR pairs")
    pooled = np.vstack([residual_pairs(bag, run, args.params)
                        for bag, run in zip(args.pairs[::2], args.pairs[1::2])])
    print("By the travel between the two sightings (the batch's poses)")
    table(pooled, 4, DISPLACEMENT_BINS, "travel (m)")
    print("\nBy the turn between them")
    table(pooled, 5, HEADING_BINS, "turn (deg)")


if __name__ == "__main__":
    main()
