"""Are the camera's range and bearing outliers one event or two?  And what the batch optimum
makes of the answer (docs/RESULTS.md, "UTIAS MRCLAM", variant 47).

    python docs/scripts/mrclam_per_axis_tails.py tails [--data-dir ../shared/datasets/mrclam]
    OMP_NUM_THREADS=1 python docs/scripts/mrclam_per_axis_tails.py batch [--nu-range NU] [--nu-bearing NU] \
        -- BAG --params config/mrclam.yaml --params RUN/noise.yaml --output OUT --seed 0 --no-plot

``tails``: the range and bearing errors against the Vicon poses and the survey
(mrclam_sensor_truth.py), each standardised by its median and MAD, per run of the first 600 s:
kurtosis of each, the share beyond 3 MADs of each on its own and given the other beyond 3, and the
correlation of their magnitudes.  One shared latent scale (the 2-D Student-t) says an outlier in
one is an outlier in the other.

``batch``: ``online-em-slam run ... --method batch`` (the maximum a posteriori of online EM's
model, offline/batch.py) with each observation's range and bearing as two factors, each a 1-D
Student-t: cost (nu + 1) / 2 log(1 + e^2 / (nu sigma^2)), a Cauchy kernel with k^2 = nu + 1 on
the error whitened by sigma^2 nu / (nu + 1) (observation_factors.py has the 2-D case).  sigma^2
the diagonal of the learned R (rho is 0 to 3e-4 on MRCLAM), nu the learned dof unless given per
axis.  A sensor at the base's origin only (MRCLAM's).
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np


def tails(data_dir: str) -> None:
    from pathlib import Path

    from mrclam_sensor_truth import errors, mad
    from online_em_slam.datasets.mrclam.benchmark import dataset_source
    from online_em_slam.datasets.mrclam.dataset import load_mrclam

    print("| run | kurtosis range / bearing | P(bearing > 3) | P(bearing > 3 given range > 3) | P(range > 3) | "
          "P(range > 3 given bearing > 3) | corr(abs) |\n|---|---|---|---|---|---|---|")
    for dataset in (1, 9):
        for robot in range(1, 6):
            run = load_mrclam(dataset_source(Path(data_dir), dataset), robot, 600)
            e_r, e_b = errors(run)
            z_r, z_b = ((e - np.median(e)) / mad(e) for e in (e_r, e_b))
            out_r, out_b = np.abs(z_r) > 3, np.abs(z_b) > 3
            kurtosis = [float(np.mean(z ** 4) / np.mean(z ** 2) ** 2) for z in (z_r, z_b)]
            print(f"| D{dataset} R{robot} | {kurtosis[0]:.1f} / {kurtosis[1]:.1f} | {out_b.mean():.3f} | "
                  f"{out_b[out_r].mean():.3f} | {out_r.mean():.3f} | {out_r[out_b].mean():.3f} | "
                  f"{np.corrcoef(np.abs(z_r), np.abs(z_b))[0, 1]:+.2f} |")


def per_axis_batch(nu_range: float | None, nu_bearing: float | None, run_args: list[str]) -> int:
    from online_em_slam.offline import batch, cli
    from online_em_slam.offline.observation_factors import lever_arm_measurement
    from online_em_slam.core.models.angles import wrap_angle

    def axis_model(gtsam, variance: float, nu: float):
        whitened = gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(variance * nu / (nu + 1.0)))
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(math.sqrt(nu + 1.0)),
                                              whitened)

    def axis_factor(gtsam, model, pose_key, landmark_key, y, axis: int):
        def error(this, values, jacobians):
            pose = values.atPose2(this.keys()[0])
            h, H_x, H_l = lever_arm_measurement((pose.x(), pose.y(), pose.theta()),
                                                np.asarray(values.atPoint2(this.keys()[1]), float), (0.0, 0.0, 0.0))
            if jacobians is not None:
                jacobians[0], jacobians[1] = H_x[axis:axis + 1], H_l[axis:axis + 1]
            e = h[axis] - y[axis]
            return np.array([wrap_angle(e) if axis == 1 else e])
        return gtsam.CustomFactor(model, [pose_key, landmark_key], error)

    def add_step(gtsam, graph, problem, config, k, by_pose):
        if config.sensor.offset_x or config.sensor.offset_y:
            raise SystemExit("per-axis batch: a sensor at the base's origin only")
        X, L = batch.symbols(gtsam)
        if k not in problem.chain_starts:
            increment = problem.increments[k - 1]
            cov = batch.tangent_covariance(increment, problem.motion_covariances[k - 1])
            graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(*increment),
                                               gtsam.noiseModel.Gaussian.Covariance(cov)))
        nu = (nu_range or float(config.noise.dof), nu_bearing or float(config.noise.dof))
        rows = slice(by_pose[k], by_pose[k + 1])
        for j, y, R in zip(problem.obs_id[rows], problem.obs_y[rows], problem.obs_R[rows]):
            for axis in (0, 1):
                graph.add(axis_factor(gtsam, axis_model(gtsam, float(R[axis, axis]), nu[axis]), X(k), L(int(j)),
                                      np.array(y, dtype=float), axis))

    batch._add_step = add_step
    return cli.main(["run", *run_args, "--method", "batch"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("tails")
    t.add_argument("--data-dir", default="../shared/datasets/mrclam")
    b = sub.add_parser("batch")
    b.add_argument("--nu-range", type=float)
    b.add_argument("--nu-bearing", type=float)
    b.add_argument("run_args", nargs=argparse.REMAINDER, help="-- then online-em-slam run's arguments")
    args = parser.parse_args(argv)
    if args.command == "tails":
        tails(args.data_dir)
        return 0
    run_args = args.run_args[1:] if args.run_args[:1] == ["--"] else args.run_args
    return per_axis_batch(args.nu_range, args.nu_bearing, run_args)


if __name__ == "__main__":
    sys.exit(main())
