"""How well can any estimator know the motion scale from one simulated run?  The Cramer-Rao bound.

    python docs/scripts/motion_scale_bound.py [--seeds 1-10] [--steps 1500] [--learned FILE] [--output FILE]
    python docs/scripts/motion_scale_bound.py --check

The scenario of test/test_noise_learning.py.  The model linearised about the true
trajectory: the control noise w_t ~ N(0, s V) (2 per step) moves the poses
x = L G w (L the transition's products Phi(t, k), G = df/du), the scan's inliers
(the outliers left out: an oracle) y = A_x x + A_m m + e, e ~ N(0, R).  With
B~ = V^1/2 G^T L^T A_x^T R^-1 A_x L G V^1/2 and its eigenvalues l_i, the Fisher
information about s at s = 1 is

    I = 1/2 sum_i (l_i / (1 + l_i))^2

(a Gaussian's information about a covariance parameter).  Two versions: the map
known, and the map a nuisance parameter (restricted likelihood: the data projected
off the columns of A_m).  1 / sqrt(I) is the smallest standard deviation of any
unbiased estimate of s from the run.  Prints it per seed next to the learner's
scales in a noise_learning_seeds.py output (--learned).  --check compares the
eigenvalue form with 1/2 tr((S^-1 dS/ds)^2) of the dense data covariance on 40 steps.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "test"))
from test_noise_learning import TRUTH  # noqa: E402

from online_em_slam.core.config import MotionConfig, SensorConfig  # noqa: E402
from online_em_slam.core.models.motion import bicycle  # noqa: E402
from online_em_slam.core.models.observation import landmark_jacobian, pose_jacobian  # noqa: E402
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for  # noqa: E402

MEASURED = Path(__file__).resolve().parents[1] / "measurements" / "noise_learning_seeds_fifth_pass.json"


def motion_jacobians(poses: np.ndarray, controls: np.ndarray, dt: float, wheelbase: float):
    """F_t = df/dx (T, 3, 3) of the filter's bicycle model at the true poses and controls, and
    G_t = df/du (T, 3, 2), which the model folds into Q = G V G^T (--check compares the two)."""
    v, psi = controls[:, 0], controls[:, 1]
    heading = poses[:-1, 2] + psi
    c, s = np.cos(heading), np.sin(heading)
    _, F, _ = bicycle(MotionConfig(model="bicycle", wheelbase=wheelbase), poses[:-1], controls, dt)
    G = np.stack([np.stack([dt * c, -v * dt * s], -1), np.stack([dt * s, v * dt * c], -1),
                  np.stack([dt * np.sin(psi) / wheelbase, v * dt * np.cos(psi) / wheelbase], -1)], 1)
    return F, G


def observation_jacobians(pose: np.ndarray, landmarks: np.ndarray):
    """dh/dx (P, 2, 3) and dh/dm (P, 2, 2) of range and bearing: the filter's own (sensor at the base)."""
    return pose_jacobian(pose, landmarks, SensorConfig()), landmark_jacobian(pose, landmarks)


def transfer(F: np.ndarray) -> np.ndarray:
    """L (3T, 3T): block (t, k) = Phi(t, k) = F_t ... F_{k+1} for k <= t (pose t after step t's noise)."""
    T = len(F)
    L = np.zeros((3 * T, 3 * T))
    for t in range(T):
        L[3 * t:3 * t + 3, 3 * t:3 * t + 3] = np.eye(3)
        if t:
            L[3 * t:3 * t + 3, :3 * t] = F[t] @ L[3 * t - 3:3 * t, :3 * t]
    return L


def fisher_information(seed: int, steps: int) -> dict:
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=0.1, n_steps=steps, **TRUTH))
    cfg = scenario.config
    F, G = motion_jacobians(scenario.true_poses, scenario.true_controls, cfg.dt, cfg.wheelbase)
    R_inv = np.diag([1 / cfg.sigma_range ** 2, 1 / cfg.sigma_bearing ** 2])
    T, M = len(F), len(scenario.landmarks)
    B = np.zeros((T, 3, 3))                         # A_x^T R^-1 A_x, block diagonal
    C = np.zeros((T, 3, 2 * M))                     # A_x^T R^-1 A_m
    D = np.zeros((2 * M, 2 * M))                    # A_m^T R^-1 A_m
    for t, step in enumerate(scenario.steps):
        ids = step.true_ids[~step.outlier]
        Hx, Hm = observation_jacobians(scenario.true_poses[t + 1], scenario.landmarks[ids])
        B[t] = np.einsum("pai,ab,pbj->ij", Hx, R_inv, Hx)
        for p, k in enumerate(ids):
            C[t, :, 2 * k:2 * k + 2] = Hx[p].T @ R_inv @ Hm[p]
            D[2 * k:2 * k + 2, 2 * k:2 * k + 2] += Hm[p].T @ R_inv @ Hm[p]
    root_V = np.array([cfg.sigma_speed, cfg.sigma_steering])
    LG = transfer(F) @ _block_diagonal(G * root_V)          # (3T, 2T): x = LG w, w ~ N(0, s I)
    Bd = _block_diagonal(B)
    known = LG.T @ Bd @ LG
    seen = np.flatnonzero(np.diag(D) > 0)
    cross = LG.T @ C.reshape(3 * T, 2 * M)[:, seen]
    nuisance = known - cross @ np.linalg.solve(D[np.ix_(seen, seen)], cross.T)
    info = {name: 0.5 * float(np.sum((lam / (1 + lam)) ** 2))
            for name, lam in (("map known", np.linalg.eigvalsh(known)), ("map estimated", np.linalg.eigvalsh(nuisance)))}
    return {name: 1 / math.sqrt(value) for name, value in info.items()}


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """(T, a, b) -> (T a, T b)."""
    T, a, b = blocks.shape
    out = np.zeros((T, a, T, b))
    out[np.arange(T), :, np.arange(T), :] = blocks
    return out.reshape(T * a, T * b)


def dense_check(seed: int = 3, steps: int = 40) -> None:
    """The eigenvalue forms against 1/2 tr((S^-1 dS)^2) and its restricted version, S the
    data's covariance A_x L G G^T L^T A_x^T + R built densely."""
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=0.1, n_steps=steps, **TRUTH))
    cfg = scenario.config
    F, G = motion_jacobians(scenario.true_poses, scenario.true_controls, cfg.dt, cfg.wheelbase)
    Ax, Am = [], []
    for t, step in enumerate(scenario.steps):
        ids = step.true_ids[~step.outlier]
        Hx, Hm = observation_jacobians(scenario.true_poses[t + 1], scenario.landmarks[ids])
        for p, k in enumerate(ids):
            row_x, row_m = np.zeros((2, 3 * steps)), np.zeros((2, 2 * len(scenario.landmarks)))
            row_x[:, 3 * t:3 * t + 3], row_m[:, 2 * k:2 * k + 2] = Hx[p], Hm[p]
            Ax.append(row_x)
            Am.append(row_m)
    _, _, Q = bicycle(slam_config_for(scenario).motion, scenario.true_poses[:-1], scenario.true_controls, cfg.dt)
    V = np.diag([cfg.sigma_speed ** 2, cfg.sigma_steering ** 2])
    print("G V G^T against the filter's Q: largest difference", float(np.abs(G @ V @ G.transpose(0, 2, 1) - Q).max()))
    Ax, Am = np.vstack(Ax), np.vstack(Am)
    Am = Am[:, np.abs(Am).sum(axis=0) > 0]
    LG = transfer(F) @ _block_diagonal(G * np.array([cfg.sigma_speed, cfg.sigma_steering]))
    dS = Ax @ LG @ LG.T @ Ax.T
    S_inv = np.linalg.inv(dS + np.diag(np.tile([cfg.sigma_range ** 2, cfg.sigma_bearing ** 2], len(Ax) // 2)))
    Pi = S_inv - S_inv @ Am @ np.linalg.solve(Am.T @ S_inv @ Am, Am.T @ S_inv)
    dense = {"map known": 1 / math.sqrt(0.5 * np.trace(S_inv @ dS @ S_inv @ dS)),
             "map estimated": 1 / math.sqrt(0.5 * np.trace(Pi @ dS @ Pi @ dS))}
    print("dense:", dense)
    print("eigenvalues:", fisher_information(seed, steps))


def learned_scales(path: Path) -> dict:
    if not path.exists():
        return {}
    data = json.loads(path.read_text())
    return {row["seed"]: (row["3x too large"]["motion_scale"], row["3x too small"]["motion_scale"])
            for part in data.values() if isinstance(part, dict) for row in part["runs"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1-10")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--learned", type=Path, default=MEASURED)
    parser.add_argument("--output", type=Path)
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    if args.check:
        dense_check()
        return
    first, last = map(int, args.seeds.split("-"))
    learned = learned_scales(args.learned)
    rows = []
    for seed in range(first, last + 1):
        bound = fisher_information(seed, args.steps)
        rows.append({"seed": seed, **bound, "learned": learned.get(seed)})
        print(seed, {k: round(v, 4) for k, v in bound.items()}, learned.get(seed), flush=True)
    for name in ("map known", "map estimated"):
        print(f"bound on the relative standard deviation, {name}: mean {np.mean([r[name] for r in rows]):.4f}")
    scales = np.array([r["learned"] for r in rows if r["learned"]])
    if scales.size:
        print(f"learned (from 9x, from 1/9x): RMS error {np.sqrt(np.mean((scales - 1) ** 2, axis=0)).round(4)}, "
              f"SD {scales.std(axis=0, ddof=1).round(4)}, mean {scales.mean(axis=0).round(4)}")
    if args.output:
        args.output.write_text(json.dumps({"steps": args.steps, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
