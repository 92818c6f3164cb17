"""Is the motion scale's bound attainable, and where does the learner lose?  Exact EKF-SLAM on the tests' scenario.

    python docs/scripts/motion_scale_ml.py [--seeds 1-80] [--gap STEPS] [--windows 3,10] [--learner N]
                                           [--outliers P] [--learn Q,...] [--output FILE]

The scenario of test/test_noise_learning.py.  One joint EKF (the EKF-SLAM baseline's
steps: pose and all 40 landmarks, the filter's own bicycle and range-bearing models, the true R, the
outliers left out: an oracle, as in motion_scale_bound.py) per value of s on a
log grid; the log-likelihood of its innovations, maximised by a parabola in log s
about the best grid value, is the maximum-likelihood scale of the run.

--gap G keeps in the likelihood only observations of landmarks also seen in the
last G steps (a partial likelihood, still unbiased): what a loop closure adds.
--windows L,... (L >= 2): the learner's statistic (M) (noise_learning.prediction_statistic,
window L, map term R / (n - 1)) on the EKF's posteriors at s = 1, the pose
spread conditioned on the map as the particle filter's is: the statistic's own
efficiency, without the particle filter.  --learner N: the learner itself (N particles,
learning on, started from the true noise; with --outliers 0 on data without them,
with --learn motion_scale learning only that), next to the ML of the same run.
Prints mean, standard deviation and runs more than 15 % off per estimator.
Two processes; about 7 minutes for 80 seeds.
"""
from __future__ import annotations

import online_em_slam  # noqa: F401  (first: one BLAS thread per worker process)

import argparse
import json
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "test"))
from test_noise_learning import TRUTH, run as run_learner, started_wrong, true_motion_scale  # noqa: E402

from online_em_slam.baselines.ekf_slam import augment, joint_innovation, kalman_update, predict_joint  # noqa: E402
from online_em_slam.core.config import SensorConfig  # noqa: E402
from online_em_slam.core.em.noise.motion_noise import MotionSteps, prediction_statistic  # noqa: E402
from online_em_slam.core.em.segment_factors import motion_residual  # noqa: E402
from online_em_slam.core.models.motion import bicycle  # noqa: E402
from online_em_slam.core.models.observation import innovation, pose_jacobian, predict_observation  # noqa: E402
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for  # noqa: E402

SENSOR = SensorConfig()
GRID = np.exp(np.linspace(np.log(0.55), np.log(1.8), 15))


class JointEkf:
    """The EKF-SLAM baseline's steps (predict_joint, joint_innovation, kalman_update, augment)
    with the motion covariance x ``scale`` and landmarks in the order first seen."""

    def __init__(self, scenario, scale: float) -> None:
        self.scenario, self.scale = scenario, scale
        self.motion = slam_config_for(scenario).motion
        cfg = scenario.config
        self.R = np.diag([cfg.sigma_range ** 2, cfg.sigma_bearing ** 2])
        self.x, self.P = scenario.initial_pose.astype(float).copy(), np.zeros((3, 3))
        self.slot = np.full(len(scenario.landmarks), -1)

    @property
    def known(self) -> np.ndarray:
        return self.slot >= 0

    def landmarks(self, ids: np.ndarray) -> np.ndarray:
        return self.x[3:].reshape(-1, 2)[self.slot[ids]]

    def predict(self, control: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motion step; returns (F, Q at scale 1)."""
        mean, F, Q = bicycle(self.motion, self.x[None, :3], control[None], self.scenario.config.dt)
        self.x, self.P = predict_joint(self.x, self.P, mean[0], F[0], self.scale * Q[0])
        return F[0], Q[0]

    def update(self, ids: np.ndarray, z: np.ndarray, counted: np.ndarray) -> float:
        """Joint update with known landmarks ``ids`` (k,), observations z (k, 2); returns the
        log-likelihood of the ``counted`` ones' innovations (their marginal)."""
        R = np.broadcast_to(self.R, (ids.size, 2, 2))
        nu, H, Rb = joint_innovation(self.x, self.P, z, R, self.slot[ids], SENSOR)
        S = H @ self.P @ H.T + Rb
        self.x, self.P = kalman_update(self.x, self.P, nu, H, Rb)
        keep = np.repeat(counted, 2)
        if not keep.any():
            return 0.0
        L = np.linalg.cholesky(S[np.ix_(keep, keep)])
        a = np.linalg.solve(L, nu[keep])
        return float(-0.5 * a @ a - np.log(np.diag(L)).sum())

    def add(self, j: int, z: np.ndarray) -> None:
        """A new landmark from its first observation (no information about s)."""
        self.slot[j] = (self.x.size - 3) // 2
        self.x, self.P = augment(self.x, self.P, z, self.R, SENSOR)

    def pose_spread_given_map(self) -> np.ndarray:
        """Cov(pose | landmarks known so far): the spread of a filter that holds the map as a parameter."""
        if self.x.size == 3:
            return self.P.copy()
        cross = self.P[:3, 3:]
        return self.P[:3, :3] - cross @ np.linalg.solve(self.P[3:, 3:], cross.T)


def run(scenario, scale: float, gap: int, record: bool = False):
    """(log-likelihood, per-step records for the window statistic or None)."""
    ekf, last, loglik, records = JointEkf(scenario, scale), np.full(len(scenario.landmarks), -10 ** 9), 0.0, []
    for t, step in enumerate(scenario.steps):
        F, Q = ekf.predict(step.control)
        predicted = ekf.x[:3].copy()
        inlier = ~step.outlier
        ids, z = step.true_ids[inlier], np.stack([step.ranges[inlier], step.bearings[inlier]], -1)
        old = ekf.known[ids]
        prior_map = ekf.landmarks(ids[old])
        if old.any():
            loglik += ekf.update(ids[old], z[old], t - last[ids[old]] <= gap)
        for j, zj in zip(ids[~old], z[~old]):
            ekf.add(j, zj)
        last[ids] = t
        if record:
            records.append(dict(c=motion_residual(predicted, ekf.x[:3].copy()), F=F, Q=Q, pose=ekf.x[:3].copy(),
                                P=ekf.pose_spread_given_map(), z=z[old], m=prior_map, ids=ids[old], seen=ids))
    return loglik, records


def window_statistic(scenario, records: list, L: int) -> float:
    """s = sum of (M)'s second entries / sum of its first over the run, at weight scale 1."""
    seen = np.zeros(len(scenario.landmarks), int)
    total = np.zeros(2)
    R = np.diag([scenario.config.sigma_range ** 2, scenario.config.sigma_bearing ** 2])
    for t, r in enumerate(records):
        seen[r["seen"]] += 1
        if t < L or not r["ids"].size:
            continue
        win = records[t - L:t + 1]
        steps = MotionSteps(np.array([w["c"] for w in win]), np.array([w["F"] for w in win]), np.array([w["Q"] for w in win]),
                            np.zeros((L + 1, 3, 3)), np.array([w["P"] for w in win]))
        nu = innovation(r["z"], predict_observation(r["pose"], r["m"]))
        noise = R + R / np.maximum(seen[r["ids"]] - 1, 1)[:, None, None]
        sample = prediction_statistic(steps, pose_jacobian(r["pose"], r["m"], SENSOR), nu, noise)
        if sample is not None:
            total += sample
    return float(total[1] / total[0])


def one(job: tuple) -> dict:
    seed, gap, windows, particles, outliers, learn = job
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=outliers, **TRUTH))
    loglik = np.array([run(scenario, s, gap)[0] for s in GRID])
    i = int(np.clip(np.argmax(loglik), 1, GRID.size - 2))
    a, b, _ = np.polyfit(np.log(GRID[i - 1:i + 2]), loglik[i - 1:i + 2], 2)
    row = {"seed": seed, "ml": float(np.exp(-b / (2 * a))), "loglik": loglik.tolist()}
    if windows:
        records = run(scenario, 1.0, gap, record=True)[1]
        row.update({f"window {L}": window_statistic(scenario, records, L) for L in windows})
    if particles:
        learning = {"learn": tuple(learn.split(","))} if learn else {}
        slam = run_learner(scenario, started_wrong(slam_config_for(scenario, num_particles=particles), 1.0, **learning))
        row["learner"] = true_motion_scale(slam, 1.0)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1-80")
    parser.add_argument("--gap", type=int, default=10 ** 9)
    parser.add_argument("--windows", default="")
    parser.add_argument("--learner", type=int, default=0, metavar="N")
    parser.add_argument("--outliers", type=float, default=0.1)
    parser.add_argument("--learn", default="", help="comma-separated quantities (default: the learner's default)")
    parser.add_argument("--output", type=Path)
    args = parser.parse_args()
    first, last = map(int, args.seeds.split("-"))
    windows = [int(w) for w in args.windows.split(",") if w]
    if any(L < 2 for L in windows):
        # One step's Q = G V G^T has rank 2 and the EKF no jitter: (M)'s standing-still
        # test would then depend on rounding.
        parser.error("--windows: each window at least 2 steps")
    with Pool(2) as pool:
        rows = pool.map(one, [(seed, args.gap, windows, args.learner, args.outliers, args.learn)
                              for seed in range(first, last + 1)])
    for key in ["ml"] + [f"window {L}" for L in windows] + ["learner"] * bool(args.learner):
        s = np.array([row[key] for row in rows])
        print(f"{key}: mean {s.mean():.3f}, SD {s.std(ddof=1):.3f}, "
              f"{int(np.sum(np.abs(s - 1) > 0.15))} of {s.size} runs more than 15 % off")
    if args.learner:
        ml, learner = (np.array([row[key] for row in rows]) for key in ("ml", "learner"))
        print(f"learner against ML: correlation {np.corrcoef(ml, learner)[0, 1]:.3f}, "
              f"SD of the difference {np.std(learner - ml, ddof=1):.3f}")
    if args.output:
        args.output.write_text(json.dumps({"gap": args.gap, "outliers": args.outliers, "learner": args.learner, "learn": args.learn,
                                           "grid": GRID.tolist(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
