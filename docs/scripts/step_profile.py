"""Where a filter step's time goes: the seed scenario under cProfile, self time grouped by stage.

    python docs/scripts/step_profile.py [--seed 0] [--particles 100] [--learn] [--top 12]

Runs online EM with the core's defaults (observed-information M-step; ``--learn`` adds the
noise learner, as the node's defaults do) on one seed of the seed scenario, then sums each
function's own time (cProfile tottime) into the stage its module belongs to: motion
integration, association, observation terms, M-step, noise learning, resampling and
weights, the estimator's bookkeeping, numpy itself. Prints milliseconds per filter step by
stage and the functions that cost most. cProfile adds overhead per Python call, so the
total is above the unprofiled time (docs/scripts/step_time.py); the split is what it is for.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
from collections import defaultdict

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

# (stage, substrings of the profiled file path), first match wins
STAGES = (
    ("motion integration", ("core/models/motion", "core/filter/prediction")),
    ("association", ("core/filter/association",)),
    ("observation terms", ("core/filter/observation_terms", "core/models/observation", "core/models/gaussian")),
    ("M-step", ("core/em/observed", "core/em/statistics", "core/em/complete", "core/em/step")),
    ("noise learning", ("core/em/noise/",)),
    ("resampling and weights", ("core/filter/particles", "core/weighted")),
    ("estimator bookkeeping", ("core/filter/", "core/mapping/", "core/models/angles", "core/types", "core/config")),
    ("the simulation feeding the inputs", ("experiments/",)),
    ("numpy, scipy and Python built-ins", ("numpy", "scipy", "~", "{", "<", "python3.11/")),
)


def stage_of(filename: str) -> str:
    for stage, keys in STAGES:
        if any(k in filename for k in keys):
            return stage
    return "other"


def profile(seed: int, particles: int, learn: bool) -> tuple[pstats.Stats, int]:
    scenario = simulate(ScenarioConfig(seed=seed))
    config = slam_config_for(scenario, num_particles=particles)
    if learn:
        config = replace_section(config, noise_learning=NoiseLearningConfig(enabled=True))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    profiler = cProfile.Profile()
    profiler.enable()
    for step in scenario.steps:
        feed(slam, step)
    profiler.disable()
    return pstats.Stats(profiler), slam.step_count


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--learn", action="store_true", help="noise learning on (the node's default)")
    parser.add_argument("--top", type=int, default=12)
    args = parser.parse_args(argv)
    stats, steps = profile(args.seed, args.particles, args.learn)
    by_stage, functions = defaultdict(float), []
    for (filename, line, name), (_, calls, tottime, _, _) in stats.stats.items():
        by_stage[stage_of(filename)] += tottime
        functions.append((tottime, calls, f"{filename.split('online_em_slam/')[-1]}:{line} {name}"))
    total = sum(by_stage.values())
    print(f"seed {args.seed}, N = {args.particles}, noise learning {'on' if args.learn else 'off'}: "
          f"{steps} filter steps, {1e3 * total / steps:.2f} ms per step under cProfile")
    print("| stage | ms per step | share |\n|---|---|---|")
    for stage, seconds in sorted(by_stage.items(), key=lambda kv: -kv[1]):
        print(f"| {stage} | {1e3 * seconds / steps:.3f} | {100 * seconds / total:.0f} % |")
    print("\n| function (self time) | ms per step | calls per step |\n|---|---|---|")
    for tottime, calls, where in sorted(functions, reverse=True)[:args.top]:
        print(f"| {where} | {1e3 * tottime / steps:.3f} | {calls / steps:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
