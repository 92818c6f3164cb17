"""Monte Carlo benchmark of the seed's simulated experiment (issue: accuracy benchmark).

    online-em-slam-benchmark --runs 20 --particles 100 --output results/benchmark

For each seeded replication of the simulator, every method runs on the same
inputs: online EM with each smoother, Block Online EM and its averaged
variant, FastSLAM 2.0, EKF-SLAM, and the GTSAM batch maximum-likelihood
reference (skipped with a note when gtsam is not installed).  Prints a table
and writes ``results.json``, ``table.md`` and ``landmark_error.png`` (mean
landmark error against time, the seed's figure 2).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from .core import OnlineEMSlam, SlamConfig
from .core.angles import wrap_angle
from .simulation import Scenario, ScenarioConfig, feed, simulate, slam_config_for

ONLINE_METHODS = {
    "online_em_forward": dict(smoother="forward", algorithm="online"),
    "online_em_paris": dict(smoother="paris", algorithm="online"),
    "online_em_ancestry": dict(smoother="ancestry", algorithm="online"),
    "boem": dict(smoother="forward", algorithm="block"),
    "boem_averaged": dict(smoother="forward", algorithm="block_averaged"),
}
BASELINES = ("fastslam2", "ekf_slam")
ALL_METHODS = tuple(ONLINE_METHODS) + BASELINES + ("gtsam_batch",)


@dataclass
class RunResult:
    method: str
    seed: int
    landmark_rmse: float
    pose_rmse: float
    mean_step_ms: float
    p99_step_ms: float
    mean_nees: float
    mean_true_pose_loglik: float
    n_landmarks: int
    error_curve: list[float]

    def to_dict(self) -> dict:
        return self.__dict__.copy()


def make_estimator(method: str, config: SlamConfig, scenario: Scenario):
    if method in ONLINE_METHODS:
        options = ONLINE_METHODS[method]
        config.filter.smoother = options["smoother"]
        config.em.algorithm = options["algorithm"]
        return OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if method == "fastslam2":
        from .baselines.fastslam2 import FastSlam2
        return FastSlam2(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if method == "ekf_slam":
        from .baselines.ekf_slam import EkfSlam
        return EkfSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(ALL_METHODS)}")


def landmark_errors(ids: np.ndarray, positions: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean error of each estimated landmark whose id indexes the true landmarks."""
    ids = np.asarray(ids, dtype=int)
    keep = (ids >= 0) & (ids < len(truth))
    return np.linalg.norm(np.asarray(positions)[keep] - truth[ids[keep]], axis=1)


def pose_consistency(mean: np.ndarray, cov: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """NEES of the true pose and its Gaussian log-likelihood under the estimate (thesis 003)."""
    err = truth - mean
    err[2] = wrap_angle(err[2])
    cov = cov + 1e-9 * np.eye(3)
    try:
        nees = float(err @ np.linalg.solve(cov, err))
        _, logdet = np.linalg.slogdet(cov)
    except np.linalg.LinAlgError:
        return math.nan, math.nan
    return nees, -0.5 * (nees + logdet + 3 * math.log(2 * math.pi))


def run_online(method: str, scenario: Scenario, particles: int, seed: int) -> RunResult:
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    estimator = make_estimator(method, config, scenario)
    durations, pose_sq, nees, loglik, curve = [], [], [], [], []
    for k, step in enumerate(scenario.steps):
        started = time.perf_counter()
        feed(estimator, step)
        durations.append(time.perf_counter() - started)
        estimate = estimator.pose()
        truth = scenario.true_poses[k + 1]
        pose_sq.append(float(np.sum((estimate.mean[:2] - truth[:2]) ** 2)))
        n, ll = pose_consistency(estimate.mean, estimate.covariance, truth)
        nees.append(n)
        loglik.append(ll)
        lm = estimator.landmarks()
        errors = landmark_errors(lm.ids, lm.positions, scenario.landmarks)
        curve.append(float(np.sqrt(np.mean(errors ** 2))) if errors.size else math.nan)
    lm = estimator.landmarks()
    errors = landmark_errors(lm.ids, lm.positions, scenario.landmarks)
    ms = 1e3 * np.asarray(durations)
    return RunResult(method, seed, float(np.sqrt(np.mean(errors ** 2))), float(np.sqrt(np.mean(pose_sq))),
                     float(ms.mean()), float(np.percentile(ms, 99)), float(np.nanmean(nees)),
                     float(np.nanmean(loglik)), int(len(lm)), curve)


def run_em_passes(scenario: Scenario, particles: int, seed: int, passes: int) -> list[float]:
    """Landmark RMSE after each of ``passes`` passes of online EM (forward smoother)
    over the same data, each pass starting from the previous pass's map: batch
    EM iterations, which show how far one online pass is from the EM fixed point."""
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    estimator = make_estimator("online_em_forward", config, scenario)
    rmse = []
    for index in range(passes):
        if index:
            estimator.start_new_pass(scenario.initial_pose, stamp=0.0)
        for step in scenario.steps:
            feed(estimator, step)
        lm = estimator.landmarks()
        rmse.append(float(np.sqrt(np.mean(landmark_errors(lm.ids, lm.positions, scenario.landmarks) ** 2))))
    return rmse


def em_passes_job(job: tuple[int, int, int, int]) -> list[float]:
    seed, particles, steps, passes = job
    return run_em_passes(simulate(ScenarioConfig(seed=seed, n_steps=steps)), particles, seed, passes)


def run_gtsam(scenario: Scenario, particles: int, seed: int) -> RunResult | None:
    from .baselines.gtsam_batch import batch_estimate
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    started = time.perf_counter()
    try:
        result = batch_estimate(scenario, config)
    except ImportError:
        return None
    elapsed = time.perf_counter() - started
    poses, landmarks = result.poses, result.landmarks
    seen = np.all(np.isfinite(landmarks), axis=1)
    errors = np.linalg.norm(landmarks[seen] - scenario.landmarks[seen], axis=1)
    pose_err = np.sum((poses[1:, :2] - scenario.true_poses[1:, :2]) ** 2, axis=1)
    per_step = 1e3 * elapsed / scenario.n_steps
    return RunResult("gtsam_batch", seed, float(np.sqrt(np.mean(errors ** 2))), float(np.sqrt(np.mean(pose_err))),
                     per_step, per_step, math.nan, math.nan, int(len(landmarks)), [])


def run_one(job: tuple[str, int, int, int]) -> dict | None:
    method, seed, particles, steps = job
    scenario = simulate(ScenarioConfig(seed=seed, n_steps=steps))
    result = run_gtsam(scenario, particles, seed) if method == "gtsam_batch" else run_online(
        method, scenario, particles, seed)
    return None if result is None else result.to_dict()


def summarize(results: list[dict]) -> dict[str, dict[str, float]]:
    table: dict[str, dict[str, float]] = {}
    for method in ALL_METHODS:
        rows = [r for r in results if r["method"] == method]
        if not rows:
            continue
        col = lambda key: np.array([r[key] for r in rows], dtype=float)  # noqa: E731
        lm = col("landmark_rmse")
        table[method] = {
            "runs": len(rows),
            "landmark_rmse_mean": float(np.mean(lm)),
            "landmark_rmse_median": float(np.median(lm)),
            "landmark_rmse_std": float(np.std(lm)),
            "pose_rmse_mean": float(np.mean(col("pose_rmse"))),
            "mean_step_ms": float(np.mean(col("mean_step_ms"))),
            "p99_step_ms": float(np.mean(col("p99_step_ms"))),
            "mean_nees": float(np.nanmean(col("mean_nees"))) if np.isfinite(col("mean_nees")).any() else math.nan,
            "mean_true_pose_loglik": (float(np.nanmean(col("mean_true_pose_loglik")))
                                      if np.isfinite(col("mean_true_pose_loglik")).any() else math.nan),
        }
    return table


def format_table(table: dict[str, dict[str, float]]) -> str:
    header = ("| method | runs | landmark RMSE mean (m) | median | std | pose RMSE (m) | mean step (ms) "
              "| p99 step (ms) | mean NEES (3 dof) | mean log-lik of true pose |")
    lines = [header, "|" + "---|" * 10]
    for method, row in table.items():
        lines.append(f"| {method} | {row['runs']} | {row['landmark_rmse_mean']:.3f} | {row['landmark_rmse_median']:.3f} "
                     f"| {row['landmark_rmse_std']:.3f} | {row['pose_rmse_mean']:.3f} | {row['mean_step_ms']:.3f} "
                     f"| {row['p99_step_ms']:.3f} | {row['mean_nees']:.2f} | {row['mean_true_pose_loglik']:.2f} |")
    return "\n".join(lines)


def plot_curves(results: list[dict], path: str, dt: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for method in ALL_METHODS:
        curves = [r["error_curve"] for r in results if r["method"] == method and r["error_curve"]]
        if not curves:
            continue
        mean = np.nanmean(np.array(curves, dtype=float), axis=0)
        ax.plot(np.arange(1, mean.size + 1) * dt, mean, label=method)
    gtsam = [r["landmark_rmse"] for r in results if r["method"] == "gtsam_batch"]
    if gtsam:
        ax.axhline(float(np.mean(gtsam)), color="k", linestyle="--", label="gtsam_batch (final)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("landmark RMSE over mapped landmarks (m)")
    ax.set_title("Mean landmark error against time (seed figure 2)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _pool_map(function, jobs: list, workers: int) -> list:
    """Map over worker processes, each with one BLAS thread: the per-step
    matrices are small, and workers competing for cores would distort timings."""
    if workers <= 1:
        return [function(job) for job in jobs]
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    from multiprocessing import get_context
    with get_context("spawn").Pool(workers) as pool:
        return list(pool.imap(function, jobs))


def em_passes_main(args) -> int:
    """``--em-passes K``: mean landmark RMSE after each pass, written to em_passes.json."""
    jobs = [(seed, args.particles, args.steps, args.em_passes) for seed in range(args.runs)]
    curves = np.array(_pool_map(em_passes_job, jobs, args.jobs))                      # (runs, K)
    lines = ["| pass | landmark RMSE mean (m) | median | std |", "|---|---|---|---|"]
    for k in range(args.em_passes):
        column = curves[:, k]
        lines.append(f"| {k + 1} | {column.mean():.3f} | {np.median(column):.3f} | {column.std(ddof=1) if len(column) > 1 else 0.0:.3f} |")
    text = "\n".join(lines)
    print(text)
    with open(os.path.join(args.output, "em_passes.json"), "w") as handle:
        json.dump({"meta": {"runs": args.runs, "particles": args.particles, "steps": args.steps,
                            "passes": args.em_passes},
                   "rmse_per_pass": curves.tolist(), "mean": curves.mean(axis=0).tolist()}, handle, indent=1)
    print(f"wrote {args.output}/em_passes.json")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=20, help="Monte Carlo replications (seeds 0..runs-1)")
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--steps", type=int, default=1500, help="simulated steps per run")
    parser.add_argument("--methods", nargs="+", default=list(ALL_METHODS), choices=ALL_METHODS)
    parser.add_argument("--jobs", type=int, default=1,
                        help="worker processes (timings are honest with jobs <= cores)")
    parser.add_argument("--output", default="results/benchmark")
    parser.add_argument("--em-passes", type=int, default=0, metavar="K",
                        help="instead of the comparison, run K passes of online EM over each run's data "
                             "(batch EM iterations) and report the landmark RMSE after each pass")
    args = parser.parse_args(argv)
    os.makedirs(args.output, exist_ok=True)
    if args.em_passes > 0:
        return em_passes_main(args)
    jobs = [(m, s, args.particles, args.steps) for s in range(args.runs) for m in args.methods]
    started = time.perf_counter()
    if args.jobs > 1:
        results = [r for r in _pool_map(run_one, jobs, args.jobs) if r is not None]
    else:
        results = []
        for i, job in enumerate(jobs, 1):
            result = run_one(job)
            if result is not None:
                results.append(result)
            print(f"\r{i}/{len(jobs)} {job[0]} seed {job[1]}", end="", flush=True)
        print()
    table = summarize(results)
    text = format_table(table)
    print(text)
    meta = {"runs": args.runs, "particles": args.particles, "steps": args.steps,
            "wall_time_s": time.perf_counter() - started, "cpu_count": os.cpu_count()}
    with open(os.path.join(args.output, "results.json"), "w") as handle:
        json.dump({"meta": meta, "summary": table, "runs": results}, handle, indent=1)
    with open(os.path.join(args.output, "table.md"), "w") as handle:
        handle.write(text + "\n")
    plot_curves(results, os.path.join(args.output, "landmark_error.png"), ScenarioConfig().dt)
    print(f"wrote {args.output}/results.json, table.md, landmark_error.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
