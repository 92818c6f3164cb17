"""Batch maximum-likelihood reference with GTSAM (known association).

The whole run is one nonlinear least-squares problem (full SLAM):

    min  |X_0 - X_init|^2_P0
       + sum_k |Log( (X_{k-1}^-1 X_k)^-1 z_k )|^2_{Sigma_k}          odometry from controls  (B1)
       + sum_{k,j} |(bearing, range)(X_k, theta_j) - y_kj|^2_R'     observations             (B2)

solved by Levenberg-Marquardt.  z_k and Sigma_k come from the motion model
evaluated at the origin, i.e. in the body frame of X_{k-1}:
z_k = f(0, u~_k), Sigma_body = G Q G^T (compounded over sub-steps) + jitter, then
expressed in the Pose2 tangent space at z_k (first order: the translation part
rotated by -dphi_k).  R' is R reordered to GTSAM's (bearing, range).
This is the batch ML estimate the online methods try to reach; gtsam is an
optional benchmark dependency, imported inside :func:`batch_estimate`.

The same problem on recorded inputs (a bag's event stream, the estimator's own
motion bookkeeping) is offline/batch.py's ``batch_from_inputs``, made a run by
offline/batch_run.py (``online-em-slam run --method batch``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.config import SlamConfig
from ..core.models.motion import propagate, step_jitter
from ..core.models.observation import inverse_observation, noise_covariance


@dataclass
class BatchResult:
    """Optimised trajectory (T+1, 3) and landmarks (M, 2) (rows of unobserved ids are NaN)."""

    poses: np.ndarray
    landmarks: np.ndarray
    initial_poses: np.ndarray
    initial_landmarks: np.ndarray
    initial_error: float
    final_error: float
    iterations: int


def relative_motion(config: SlamConfig, control: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame increment z = f(0, u) and its covariance, compounded over sub-steps
    (Sigma <- F Sigma F^T + G Q G^T), plus the per-step jitter so Sigma is invertible
    (the bicycle's 2 control noises span only a plane of the 3-D pose space)."""
    motion = config.motion
    n = max(1, int(math.ceil(dt / motion.max_step - 1e-9)))
    pose, cov = np.zeros((1, 3)), np.zeros((3, 3))
    for _ in range(n):
        pose, F, Q = propagate(motion, pose, control, dt / n)
        cov = F[0] @ cov @ F[0].T + Q[0]
    return pose[0], cov + step_jitter(motion)


def tangent_covariance(increment: np.ndarray, body_cov: np.ndarray) -> np.ndarray:
    """Sigma in Pose2 local coordinates at z: z Exp(xi) ~ (t + R(dphi) xi_t, dphi + xi_phi),
    so xi = blockdiag(R(-dphi), 1) delta and Sigma_xi = T Sigma_body T^T."""
    c, s = math.cos(increment[2]), math.sin(increment[2])
    T = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    out = T @ body_cov @ T.T
    return 0.5 * (out + out.T)


def compose(pose: np.ndarray, increment: np.ndarray) -> np.ndarray:
    """Pose composition X (+) z for the dead-reckoning initial guess."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([pose[0] + c * increment[0] - s * increment[1],
                     pose[1] + s * increment[0] + c * increment[1],
                     wrap_angle(pose[2] + increment[2])])


def dead_reckoning(scenario, config: SlamConfig, n_landmarks: int) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop trajectory X_k = X_{k-1} (+) z_k and each landmark placed by inverting
    its first observation there: the optimiser's initial guess, and the no-SLAM
    reference that every SLAM estimate should beat.  Pure numpy (no gtsam)."""
    pose = np.asarray(scenario.initial_pose, dtype=float).copy()
    poses = [pose.copy()]
    landmarks = np.full((n_landmarks, 2), np.nan)
    for step in scenario.steps:
        increment, _ = relative_motion(config, np.asarray(step.control, float),
                                       float(step.stamp - step.control_stamp))
        pose = compose(pose, increment)
        poses.append(pose.copy())
        for r, b, j in zip(step.ranges, step.bearings, step.true_ids):
            if 0 <= j < n_landmarks and np.isnan(landmarks[j, 0]):
                sensor_pose = pose + np.array([0.0, 0.0, config.sensor.offset_yaw])
                landmarks[j] = inverse_observation(sensor_pose, np.array([r, b]))
    return np.array(poses), landmarks


def batch_estimate(scenario, config: SlamConfig, n_landmarks: int | None = None,
                   max_iterations: int = 100, initial_pose_std: tuple[float, float, float] = (1e-3, 1e-3, 1e-4)
                   ) -> BatchResult:
    """Build (B1)-(B2) from a Scenario-like run and optimise it.

    ``scenario`` needs ``initial_pose`` and ``steps`` whose items have
    control_stamp, stamp, control, ranges, bearings and true_ids (the true
    association is used whatever ``known_ids`` was).  Only sensors at the base
    origin are supported (BearingRangeFactor2D has no lever arm); a yaw offset
    is folded into the bearings.
    """
    import gtsam  # optional dependency, see module docstring

    sensor = config.sensor
    if sensor.offset_x != 0.0 or sensor.offset_y != 0.0:
        raise ValueError("batch_estimate supports sensor.offset_x = offset_y = 0 only")
    if config.motion.uses_odometry:
        raise ValueError("batch_estimate needs a control-driven motion model")
    steps = scenario.steps
    if n_landmarks is None and getattr(scenario, "landmarks", None) is not None:
        n_landmarks = len(scenario.landmarks)
    if n_landmarks is None:
        n_landmarks = 1 + max((int(s.true_ids.max()) for s in steps if len(s.true_ids)), default=-1)
    initial, landmark_guess = dead_reckoning(scenario, config, n_landmarks)
    graph, values = _factor_graph(gtsam, scenario, config, n_landmarks, initial, initial_pose_std)
    X, L = symbols(gtsam)
    observed = np.flatnonzero(np.isfinite(landmark_guess[:, 0]))
    for j in observed:
        values.insert(L(int(j)), gtsam.Point2(float(landmark_guess[j, 0]), float(landmark_guess[j, 1])))

    optimizer, result = levenberg_marquardt(gtsam, graph, values, max_iterations)

    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(X(k)) for k in range(len(steps) + 1))])
    landmarks = np.full((n_landmarks, 2), np.nan)
    for j in observed:
        landmarks[j] = np.asarray(result.atPoint2(L(int(j))), dtype=float).reshape(2)
    return BatchResult(poses=poses, landmarks=landmarks, initial_poses=initial,
                       initial_landmarks=landmark_guess,
                       initial_error=float(graph.error(values)), final_error=float(graph.error(result)),
                       iterations=int(optimizer.iterations()))


def levenberg_marquardt(gtsam, graph, values, max_iterations: int):
    """(optimizer, optimum) of Levenberg-Marquardt from ``values``, to relative and absolute error 1e-8."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-8)
    params.setAbsoluteErrorTol(1e-8)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    return optimizer, optimizer.optimize()


def symbols(gtsam):
    """Keys of pose k and landmark j."""
    return (lambda k: gtsam.symbol("x", k)), (lambda j: gtsam.symbol("l", j))


def _factor_graph(gtsam, scenario, config: SlamConfig, n_landmarks: int, initial: np.ndarray,
                  initial_pose_std) -> tuple:
    """(B1) prior and between factors from the controls, (B2) bearing-range factors; pose values."""
    X, L = symbols(gtsam)
    sensor = config.sensor
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*initial[0]),
                                     gtsam.noiseModel.Diagonal.Sigmas(np.asarray(initial_pose_std, float))))
    values.insert(X(0), gtsam.Pose2(*initial[0]))
    for k, step in enumerate(scenario.steps, start=1):
        increment, body_cov = relative_motion(config, np.asarray(step.control, float),
                                              float(step.stamp - step.control_stamp))
        graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(*increment),
                                           gtsam.noiseModel.Gaussian.Covariance(
                                               tangent_covariance(increment, body_cov))))
        values.insert(X(k), gtsam.Pose2(*initial[k]))
        if not len(step.ranges):
            continue
        bearings = wrap_angle(np.asarray(step.bearings) + sensor.offset_yaw)
        R = noise_covariance(config.noise, step.ranges)
        for r, b, j, Rj in zip(step.ranges, np.atleast_1d(bearings), step.true_ids, R):
            if not 0 <= j < n_landmarks:
                continue
            # GTSAM orders the BearingRange measurement as (bearing, range).
            cov = np.array([[Rj[1, 1], Rj[0, 1]], [Rj[1, 0], Rj[0, 0]]])
            graph.add(gtsam.BearingRangeFactor2D(X(k), L(int(j)), gtsam.Rot2(float(b)), float(r),
                                                 gtsam.noiseModel.Gaussian.Covariance(cov)))
    return graph, values
