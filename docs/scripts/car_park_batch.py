"""Batch maximum-likelihood map of the Car Park bag: where a consistent estimator's map lies.

    python docs/scripts/car_park_batch.py BAG RUN_DIR [--output docs/measurements/car_park_batch.json]

The whole run as one nonlinear least-squares problem over every scan pose and
every landmark, with the same models, noise and first-pose prior as the online
runs (config/hand_tuned/car_park.yaml, the initial pose from GPS that ``online-em-slam run``
uses), solved to convergence by Gauss-Newton (finite-difference sparse Jacobian, so
the solver shares no Jacobian code with the estimator):

    |X_0 - X_init|^2_P0 + sum_k |(X_{k-1}^-1 X_k) - z_k|^2_{Sigma_k}
                        + sum_{k,j} w_kj |y_kj - h(X_k, theta_j)|^2_R

z_k, Sigma_k: the controls between scans compounded by the motion model from the
origin (motion.integrate_segments) plus the per-step jitter; w_kj: the mixture's
expected precision weight, re-estimated by iteratively reweighted least squares
(the EM of the mixture noise).  The association is taken from RUN_DIR (an
``online-em-slam run`` output: each observation goes to the nearest landmark of
the run's final map seen from the run's pose, within --gate metres).  Prints the
beacon RMSE with its shape and frame parts next to the run's, and writes them.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize._numdiff import approx_derivative
from scipy.sparse import csr_matrix, lil_matrix
from scipy.sparse.linalg import spsolve

from online_em_slam.core.models import motion as motion_models
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.models.observation import (component_precision_weight, inverse_observation,
                                                    noise_covariance, noise_loglik, predict_observation,
                                                    sensor_poses)
from online_em_slam.offline.evaluation import landmark_metrics
from online_em_slam.parameters.yaml_file import config_from_params, load_params
from online_em_slam.pipeline import CONTROL, OBSERVATIONS
from online_em_slam.offline.runner import read_inputs

PRIOR_STD = np.array([1e-3, 1e-3, 1e-4])      # the estimators' floor for initial_pose_std = 0


def scans_and_motion(events, config):
    """Per scan: its stamp, observations and the motion increment (z, Sigma) from the previous scan."""
    control, last = None, None
    controls, dts, scans = [], [], []
    for kind, stamp, payload, *_ in sorted(events, key=lambda e: e[1]):
        if last is not None and control is not None and stamp > last:
            controls.append(control)
            dts.append(stamp - last)
        if kind == CONTROL:
            control, last = np.asarray(payload, dtype=float), stamp
        elif kind == OBSERVATIONS and control is not None:
            z, sigma = _compound(config.motion, controls, dts)
            scans.append((stamp, payload, z, sigma))
            controls, dts, last = [], [], stamp
    return scans


def _compound(motion, controls, dts):
    if not controls:
        return np.zeros(3), motion_models.step_jitter(motion)
    mean, cov, _ = motion_models.integrate_segments(motion, np.zeros((1, 3)), np.zeros((1, 3, 3)),
                                                    np.array(controls), np.array(dts), with_jacobian=True)
    return mean[0], cov[0] + motion_models.step_jitter(motion)


def run_landmarks(run_dir: Path) -> np.ndarray:
    """(M, 2) the final map of an ``online-em-slam run`` output."""
    with open(run_dir / "landmarks.csv") as f:
        return np.array([[float(r["x"]), float(r["y"])] for r in csv.DictReader(f)])


def run_poses(run_dir: Path, stamps) -> np.ndarray:
    """(K, 3) the run's base poses at ``stamps`` (the nearest trajectory row)."""
    traj = np.loadtxt(run_dir / "trajectory.csv", delimiter=",", skiprows=1)
    return traj[np.abs(traj[:, 0][None] - np.asarray(stamps)[:, None]).argmin(axis=1), 1:4]


def associate(scans, config, poses: np.ndarray, landmarks: np.ndarray, gate: float):
    """(scan index, landmark index, y (2,)) for each observation within ``gate`` of a landmark
    seen from the run's pose at that scan; and the landmarks kept (seen at least 3 times)."""
    rows = []
    for k, ((_, obs, _, _), pose) in enumerate(zip(scans, poses)):
        sp = sensor_poses(pose[None], config.sensor)[0]
        for y in np.stack([obs.ranges, obs.bearings], axis=1):
            d = np.linalg.norm(landmarks - inverse_observation(sp, y), axis=1)
            if d.min() < gate:
                rows.append((k, int(d.argmin()), y))
    # A landmark seen fewer than 3 times has no determined position: leave it out.
    counts = np.bincount([r[1] for r in rows], minlength=len(landmarks))
    keep = counts >= 3
    index = np.cumsum(keep) - 1
    return [(k, int(index[j]), y) for k, j, y in rows if keep[j]], landmarks[keep]


def residuals(z, scans, whitening, rows, config, init, weights):
    """Whitened residuals of prior, motion (``whitening`` W_k: W_k^T W_k = Sigma_k^-1) and
    weighted observations; and the innovations and R of the observations."""
    n = len(scans) + 1
    X, L = z[:3 * n].reshape(n, 3), z[3 * n:].reshape(-1, 2)
    prior = (X[0] - init) / PRIOR_STD
    prior[2] = wrap_angle(X[0, 2] - init[2]) / PRIOR_STD[2]
    c, s = np.cos(X[:-1, 2]), np.sin(X[:-1, 2])
    dp = X[1:, :2] - X[:-1, :2]
    rel = np.stack([c * dp[:, 0] + s * dp[:, 1], -s * dp[:, 0] + c * dp[:, 1],
                    wrap_angle(X[1:, 2] - X[:-1, 2])], axis=1)
    e = rel - np.array([sc[2] for sc in scans])
    e[:, 2] = wrap_angle(e[:, 2])
    motion = np.einsum("kij,kj->ki", whitening, e)
    k, j = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    y = np.array([r[2] for r in rows])
    pred = predict_observation(sensor_poses(X[k + 1], config.sensor), L[j])
    nu = y - pred
    nu[:, 1] = wrap_angle(nu[:, 1])
    R = noise_covariance(config.noise, y[:, 0])
    white = np.einsum("kij,kj->ki", np.linalg.cholesky(np.linalg.inv(R)).transpose(0, 2, 1), nu)
    return np.concatenate([prior, motion.ravel(), (np.sqrt(weights)[:, None] * white).ravel()]), nu, R


def sparsity(scans, rows, n_landmarks):
    n = len(scans) + 1
    m = 3 + 3 * len(scans) + 2 * len(rows)
    A = lil_matrix((m, 3 * n + 2 * n_landmarks), dtype=int)
    A[0:3, 0:3] = 1
    for k in range(len(scans)):
        A[3 + 3 * k:6 + 3 * k, 3 * k:3 * k + 6] = 1
    base = 3 + 3 * len(scans)
    for i, (k, j, _) in enumerate(rows):
        A[base + 2 * i:base + 2 * i + 2, 3 * (k + 1):3 * (k + 1) + 3] = 1
        A[base + 2 * i:base + 2 * i + 2, 3 * n + 2 * j:3 * n + 2 * j + 2] = 1
    return A


def gauss_newton(fun, z, pattern, max_iterations: int = 50, tol: float = 1e-9):
    """Gauss-Newton with a finite-difference sparse Jacobian and a sparse direct solve
    (step halving when the cost rises): converged when the step is below ``tol``."""
    cost = 0.5 * float(np.sum(fun(z) ** 2))
    for iteration in range(max_iterations):
        r = fun(z)
        J = csr_matrix(approx_derivative(fun, z, method="2-point", sparsity=pattern, f0=r))
        step = spsolve((J.T @ J).tocsc(), -(J.T @ r))
        for _ in range(20):
            trial = 0.5 * float(np.sum(fun(z + step) ** 2))
            if trial <= cost:
                break
            step = 0.5 * step
        z, cost = z + step, trial
        if np.max(np.abs(step)) < tol:
            break
    return z, cost, iteration + 1


def solve(scans, rows, poses, landmarks, config, init, rounds: int = 5):
    """IRLS over the mixture, from the run's poses and landmarks: each round solves the least
    squares with the weights of the last."""
    z = np.concatenate([init, poses.ravel(), landmarks.ravel()])
    whitening = np.array([np.linalg.cholesky(np.linalg.inv(sc[3])).T for sc in scans])
    weights = np.ones(len(rows))
    pattern = sparsity(scans, rows, len(landmarks))
    for _ in range(rounds):                          # the mixture's E-step, then the least-squares M-step
        z, cost, iterations = gauss_newton(
            lambda v: residuals(v, scans, whitening, rows, config, init, weights)[0], z, pattern)
        _, nu, R = residuals(z, scans, whitening, rows, config, init, weights)
        _, resp = noise_loglik(config.noise, nu, R)
        weights = component_precision_weight(config.noise, resp)
    return z[3 * (len(scans) + 1):].reshape(-1, 2), cost, iterations


def distance_to(batch: np.ndarray, run_dir: Path) -> dict:
    """RMS distance of a run's map to the batch map (one-to-one matching within 1 m)."""
    run = json.loads((run_dir / "metrics.json").read_text())
    m = landmark_metrics(run_landmarks(run_dir), batch, gate=1.0)
    return {"method": run["method"], "to_batch_rms": m.rmse, "matched": m.n_matched,
            "beacon_rmse": run["landmarks"]["rmse"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("run", help="an online-em-slam run output directory (association, initial guess)")
    parser.add_argument("--params", default="config/hand_tuned/car_park.yaml")
    parser.add_argument("--gate", type=float, default=1.0)
    parser.add_argument("--output", default="docs/measurements/car_park_batch.json")
    parser.add_argument("--compare", nargs="*", default=[],
                        help="more run directories: the RMS distance of each one's map to the batch map")
    args = parser.parse_args(argv)
    config, settings = config_from_params(load_params(args.params), {})
    inputs = read_inputs(args.bag, settings)
    run_dir = Path(args.run)
    run = json.loads((run_dir / "metrics.json").read_text())
    ip = run["initial_pose"]
    init = np.array([ip["x"], ip["y"], ip["yaw"]])
    scans = scans_and_motion(inputs.events, config)
    poses = run_poses(run_dir, [sc[0] for sc in scans])
    rows, landmarks = associate(scans, config, poses, run_landmarks(run_dir), args.gate)
    n_obs = sum(len(sc[1].ranges) for sc in scans)
    batch, cost, iterations = solve(scans, rows, poses, landmarks, config, init)
    metrics = landmark_metrics(batch, inputs.landmarks)
    out = {"bag": args.bag, "run": str(run_dir), "scans": len(scans), "observations": n_obs,
           "associated": len(rows), "gate": args.gate, "cost": cost, "iterations_last_round": iterations,
           "batch": {"rmse": metrics.rmse, "shape": metrics.shape_error, "frame": metrics.frame_error,
                     "matched": metrics.n_matched, "spurious": metrics.n_spurious},
           "run_method": run["method"],
           "run_landmarks": {"rmse": run["landmarks"]["rmse"], "shape": run["landmarks"]["shape_error"],
                             "frame": run["landmarks"]["frame_error"]},
           "batch_to_run_map_rms": float(np.sqrt(np.mean(np.sum((batch - landmarks) ** 2, axis=1)))),
           "landmarks_solved": len(landmarks),
           "initial_pose": ip, "batch_landmarks": batch.tolist(),
           "compared": {str(d): distance_to(batch, Path(d)) for d in args.compare}}
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
