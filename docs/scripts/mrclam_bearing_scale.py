"""The camera's bearing errors on MRCLAM against a bearing scale and a camera offset.

    python docs/scripts/mrclam_bearing_scale.py [--data-dir ../shared/datasets/mrclam] [--seconds 600]

Bearing errors against the Vicon poses and the survey (mrclam_sensor_truth.py; beyond 5 MADs
in range or bearing left out), fitted by least squares as (a) offset + k b, a lens scale
(measured = (1 + k) true + offset), and (b) offset + k b + d sin(b) / r, with a camera d
ahead of the Vicon centre as well (negative: behind).  Prints k and d with their standard errors, the residual
MAD of each fit, and the span of true bearings the run saw.
"""
import argparse
from pathlib import Path

import numpy as np

from mrclam_sensor_truth import errors, mad

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam


def fit(columns, e):
    """(coefficients, standard errors, residual MAD in degrees) of e on ``columns``."""
    A = np.column_stack(columns)
    c, *_ = np.linalg.lstsq(A, e, rcond=None)
    residual = e - A @ c
    return c, np.sqrt(np.diag(np.linalg.inv(A.T @ A)) * residual.var()), np.degrees(mad(residual))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    args = parser.parse_args()
    print("run     bearings (deg)   scale k           MAD    | k with offset d        d (m)            MAD")
    for dataset in (1, 9):
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(args.data_dir), dataset), robot, args.seconds or None)
            er, eb = errors(run)
            keep = (np.abs(eb - np.median(eb)) < 5 * mad(eb)) & (np.abs(er - np.median(er)) < 5 * mad(er))
            e, b = eb[keep], (run.measurement_bearing - eb)[keep]
            r = (run.measurement_range - er)[keep]
            one = np.ones_like(b)
            (_, k), (_, k_se), mad_k = fit([one, b], e)
            (_, k2, d), (_, k2_se, d_se), mad_kd = fit([one, b, np.sin(b) / r], e)
            print(f"D{dataset} R{robot}  {np.degrees(b.min()):+4.0f} .. {np.degrees(b.max()):+3.0f}     "
                  f"{k:+.4f} +- {k_se:.4f}  {mad_k:.3f} | {k2:+.4f} +- {k2_se:.4f}  {d:+.3f} +- {d_se:.3f}  {mad_kd:.3f}")


if __name__ == "__main__":
    main()
