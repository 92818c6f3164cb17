"""The batch reference with a rotation gain that drifts (MRCLAM variant 79, docs/measurements).

Each pose variable k gets a scalar g_k, the deviation of the rotation gain over the step into
k from the gains in the parameter files: the motion factor predicts the step's turn as
turn_k (1 + g_k); g is a random walk, g_k - g_{k-1} ~ N(0, q dt_k), g_0 ~ N(0, s0^2).  With
q -> 0 and s0 -> 0 it is the batch of ``online-em-slam run --method batch``.

    python docs/scripts/mrclam_gain_drift_batch.py Q S0 BAG OUT PARAMS [PARAMS ...]

Writes OUT as ``online-em-slam run`` does (landmarks.csv, metrics.json, trajectory.csv), scored
with the benchmark's 1 m gate.  Needs gtsam.  GTSAM custom factors in Python: about a minute per
600 s run.
"""
import sys

import numpy as np

from online_em_slam.baselines.gtsam_batch import symbols, tangent_covariance
from online_em_slam.offline import batch
from online_em_slam.offline.cli import main

CONSTANT_GAIN_GRAPH = batch.build_graph


def motion_error(increment, this, values, H):
    """Pose2 residual of the step's motion with its turn scaled by (1 + g)."""
    import gtsam
    keys = this.keys()
    g = values.atVector(keys[2])[0]
    predicted = gtsam.Pose2(increment[0], increment[1], increment[2] * (1.0 + g))
    Hb1, Hb2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    between = values.atPose2(keys[0]).between(values.atPose2(keys[1]), Hb1, Hb2)
    Hp, He = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    error = predicted.between(between, Hp, He)
    if H is not None:                    # Logmap's Jacobian taken as I (small residuals)
        H[0], H[1] = He @ Hb1, He @ Hb2
        H[2] = (Hp @ np.array([0.0, 0.0, increment[2]])).reshape(3, 1)
    return gtsam.Pose2.Logmap(error)


def difference_error(this, values, H):
    """g_k - g_{k-1} (two keys) or g_0 (one key)."""
    keys = this.keys()
    if len(keys) == 1:
        if H is not None:
            H[0] = np.ones((1, 1))
        return np.array([values.atVector(keys[0])[0]])
    if H is not None:
        H[0], H[1] = -np.ones((1, 1)), np.ones((1, 1))
    return np.array([values.atVector(keys[1])[0] - values.atVector(keys[0])[0]])


def drifting_gain_graph(q: float, s0: float):
    def build_graph(gtsam, problem, config, poses, ids, landmarks, initial_pose_std=(1e-3, 1e-3, 1e-4)):
        constant, values = CONSTANT_GAIN_GRAPH(gtsam, problem, config, poses, ids, landmarks, initial_pose_std)
        graph = gtsam.NonlinearFactorGraph()
        for i in range(constant.size()):
            if not isinstance(constant.at(i), gtsam.BetweenFactorPose2):
                graph.add(constant.at(i))
        X, G = symbols(gtsam)[0], (lambda k: gtsam.symbol("g", int(k)))
        for k in range(len(poses)):
            values.insert(G(k), np.zeros(1))
            if k in problem.chain_starts:
                graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, s0), [G(k)], difference_error))
                continue
            increment = problem.increments[k - 1].copy()
            cov = tangent_covariance(increment, problem.motion_covariances[k - 1])
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), [X(k - 1), X(k), G(k)],
                                         lambda this, v, H, inc=increment: motion_error(inc, this, v, H)))
            dt = max(float(problem.stamps[k] - problem.stamps[k - 1]), 1e-3)
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, np.sqrt(q * dt)), [G(k - 1), G(k)],
                                         difference_error))
        return graph, values
    return build_graph


if __name__ == "__main__":
    q, s0, bag, out, params = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5:]
    batch.build_graph = drifting_gain_graph(q, s0)
    argv = ["run", bag, "--output", out, "--method", "batch", "--no-plot", "--match-gate", "1.0"]
    sys.exit(main(argv + [arg for p in params for arg in ("--params", p)]))
