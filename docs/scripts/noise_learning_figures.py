"""Noise learned online in simulation: the docs/RESULTS.md "Noise learned online" tables and figure.

    python docs/scripts/noise_learning_figures.py [--seeds 1 2 3 4] [--output docs]

Truth: R with sigma_r = 0.3 m, sigma_b = 0.02 rad, 10 % outliers at 25 R, motion
noise 0.3 m/s and 0.03 rad (40 landmarks, 1500 steps).  For each seed the
estimator runs given the truth (learning off) and started with every noise
standard deviation 3x too large and 3x too small (the seed's 0.8 / 0.2 mixture
with scale 5) with learning on; then the range-dependent case
(sigma_r = 0.05 + 0.02 r) and 5 % outliers against the same run without.
Prints markdown tables and writes ``noise_learning.png``: the learned values
over time, relative to the truth, for the first seed.
"""
from __future__ import annotations

import online_em_slam  # noqa: F401  (first: one BLAS thread per worker process)

import argparse
import sys
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "test"))
from test_noise_learning import (PARTICLES, TRUTH, map_errors, started_wrong,  # noqa: E402
                                 true_motion_scale)

from online_em_slam.core import OnlineEMSlam  # noqa: E402
from online_em_slam.core.config import NoiseLearningConfig, replace_section  # noqa: E402
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for  # noqa: E402

FACTORS = (0.0, 3.0, 1 / 3)        # 0: given the truth, learning off


def run_traced(scenario, config, factor: float, every: int = 10):
    """(slam, trace (K, 5): step, sigma_r, sigma_b, motion scale (relative to the truth), outlier weight)."""
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    trace = []
    for k, step in enumerate(scenario.steps):
        feed(slam, step)
        if k % every == 0:
            learned = slam.learned_noise()
            trace.append((k, learned["sigma_range"] / TRUTH["sigma_range"],
                          learned["sigma_bearing"] / TRUTH["sigma_bearing"],
                          true_motion_scale(slam, factor or 1.0), learned["mixture_weights"][-1]))
    return slam, np.array(trace)


def main_case(job):
    seed, factor = job
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=0.1, **TRUTH))
    truth = slam_config_for(scenario, num_particles=PARTICLES)
    slam, trace = run_traced(scenario, started_wrong(truth, factor) if factor else truth, factor)
    rmse, shape = map_errors(slam, scenario)
    learned = slam.learned_noise()
    return {"seed": seed, "factor": factor, "rmse": rmse, "shape": shape, "trace": trace,
            "sigma_r": learned["sigma_range"] / TRUTH["sigma_range"],
            "sigma_b": learned["sigma_bearing"] / TRUTH["sigma_bearing"],
            "weight": learned["mixture_weights"][-1], "outlier_scale": learned["mixture_scales"][-1],
            "motion": true_motion_scale(slam, factor or 1.0)}


def range_case(seed: int) -> dict:
    scenario = simulate(ScenarioConfig(seed=seed, landmark_offset=(3.0, 6.0), range_growth=0.02,
                                       **{**TRUTH, "sigma_range": 0.05}))
    config = slam_config_for(scenario, num_particles=PARTICLES)
    config = replace_section(config, noise=replace(config.noise, sigma_range=0.3, range_growth=0.0),
                             noise_learning=NoiseLearningConfig(enabled=True,
                                                                learn=("range", "range_growth", "bearing")))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    for step in scenario.steps:
        feed(slam, step)
    learned = slam.learned_noise()
    return {"seed": seed, "a": learned["sigma_range"], "b": learned["range_growth"]}


def outlier_case(job) -> dict:
    seed, p = job
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=p, **TRUTH))
    config = slam_config_for(scenario, num_particles=PARTICLES)
    config = replace_section(config, noise=replace(config.noise, model="mixture", mixture_weights=(0.8, 0.2),
                                                   mixture_scales=(1.0, 5.0)),
                             noise_learning=NoiseLearningConfig(enabled=True))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose)
    for step in scenario.steps:
        feed(slam, step)
    learned = slam.learned_noise()
    return {"seed": seed, "p": p, "rmse": map_errors(slam, scenario)[0], "weight": learned["mixture_weights"][-1],
            "scale": learned["mixture_scales"][-1], "sigma_r": learned["sigma_range"]}


def main_table(results: list[dict]) -> str:
    truth = {r["seed"]: r for r in results if not r["factor"]}
    lines = ["| seed | start | sigma_r / truth | sigma_b / truth | outlier weight (0.10) | outlier scale (25) "
             "| motion scale / truth | map RMSE (m), given truth -> learned | shape (m), given truth -> learned |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in (r for r in results if r["factor"]):
        t = truth[r["seed"]]
        start = "3x" if r["factor"] > 1 else "1/3x"
        lines.append(f"| {r['seed']} | {start} | {r['sigma_r']:.3f} | {r['sigma_b']:.3f} | {r['weight']:.3f} | "
                     f"{r['outlier_scale']:.1f} | {r['motion']:.3f} | {t['rmse']:.3f} -> {r['rmse']:.3f} | "
                     f"{t['shape']:.3f} -> {r['shape']:.3f} |")
    return "\n".join(lines)


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    seed = results[0]["seed"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharex=True)
    titles = ("sigma_r / truth", "sigma_b / truth", "motion scale / truth")
    for r in (r for r in results if r["seed"] == seed and r["factor"]):
        label = "started 3x too large" if r["factor"] > 1 else "started 3x too small"
        for ax, column in zip(axes, (1, 2, 3)):
            ax.plot(r["trace"][:, 0], r["trace"][:, column], label=label)
    for ax, title in zip(axes, titles):
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_yscale("log")
        ax.set_ylim(0.08, 12)
        ax.set_title(title)
        ax.set_xlabel("filter step")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Noise learned online, seed {seed}: the values the learner holds (used after the warm-up)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--output", default="docs")
    args = parser.parse_args()
    with Pool(2) as pool:
        results = pool.map(main_case, [(s, f) for s in args.seeds for f in FACTORS])
        ranges = pool.map(range_case, args.seeds[:3])
        outliers = pool.map(outlier_case, [(s, p) for s in args.seeds[:2] for p in (0.0, 0.05)])
    print(main_table(results))
    print("\n| seed | a (0.05 m) | b (0.02) |\n|---|---|---|")
    for r in ranges:
        print(f"| {r['seed']} | {r['a']:.4f} | {r['b']:.4f} |")
    print("\n| seed | outliers | learned outlier weight | outlier scale | sigma_r (m) | map RMSE (m) |")
    print("|---|---|---|---|---|---|")
    for r in outliers:
        print(f"| {r['seed']} | {r['p']:.0%} | {r['weight']:.3f} | {r['scale']:.1f} | {r['sigma_r']:.3f} "
              f"| {r['rmse']:.3f} |")
    plot(results, Path(args.output) / "noise_learning.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
