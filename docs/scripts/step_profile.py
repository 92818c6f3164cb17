"""Where a filter step's time goes, by stage: the seed scenario timed stage by stage.

    python docs/scripts/step_profile.py [--seed 0] [--particles 100] [--learn] [--functions 12]

Runs online EM with the core's defaults (observed-information M-step; ``--learn`` adds the
noise learner, as the node's defaults do) on one seed of the seed scenario with a clock
around each stage of the filter step (docs/METHOD.md, "Filter step"): motion integration,
ancestors, proposal draws, association, observation terms, weights, noise learner, M-step,
commit, pruning; "the rest" is the step's own code between them (sensor poses, the step's
data, the input checks).  Each stage's time is its own (exclusive: a stage called inside
another is not counted twice), so the rows add up to the step.  A clock read costs well
under a microsecond, so the total is the unprofiled time; the script prints it and the load
average.  ``--functions K`` adds cProfile's K most expensive functions (self time; cProfile's
overhead per Python call inflates those figures, the stage table is not under it).
Use one BLAS thread (OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1) for figures to compare.
"""
from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
from collections import defaultdict

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.em.noise.learner import NoiseLearner
from online_em_slam.core.em.observed import ObservedInformationEM
from online_em_slam.core.filter import slam as slam_module
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for

# (stage, owner, attribute): the callables timed, in the order of the filter step.
STAGES = (
    ("motion integration", OnlineEMSlam, "_flush_motion"),
    ("ancestors (resampling)", OnlineEMSlam, "_select_ancestors"),
    ("proposal draws", slam_module, "sample_gaussians"),
    ("association", OnlineEMSlam, "_associate_scan"),
    ("observation terms", OnlineEMSlam, "_observation_terms"),
    ("weights", OnlineEMSlam, "_normalise"),
    ("noise learner", NoiseLearner, "update"),
    ("M-step", ObservedInformationEM, "update"),
    ("commit (anchors, ESS)", OnlineEMSlam, "_commit"),
    ("pruning", OnlineEMSlam, "_prune_tentative"),
)
REST = "the rest of the step"


class StageClock:
    """Exclusive wall time per stage: the innermost running stage owns the clock."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.stack = [REST]
        self.mark = time.perf_counter()

    def _switch(self) -> None:
        now = time.perf_counter()
        self.seconds[self.stack[-1]] += now - self.mark
        self.mark = now

    def timed(self, stage: str, function):
        def wrapper(*args, **kwargs):
            self._switch()
            self.stack.append(stage)
            try:
                return function(*args, **kwargs)
            finally:
                self._switch()
                self.stack.pop()
        return wrapper


def instrument(clock: StageClock) -> list[tuple[object, str, object]]:
    """Wrap every stage's callable; returns what to put back."""
    saved = []
    for stage, owner, name in STAGES:
        original = getattr(owner, name)
        saved.append((owner, name, original))
        setattr(owner, name, clock.timed(stage, original))
    return saved


def run(seed: int, particles: int, learn: bool, clock: StageClock | None = None,
        profiler: cProfile.Profile | None = None) -> tuple[float, int]:
    """Seconds spent feeding the scenario and the number of filter steps."""
    scenario = simulate(ScenarioConfig(seed=seed))
    config = slam_config_for(scenario, num_particles=particles)
    if learn:
        config = replace_section(config, noise_learning=NoiseLearningConfig(enabled=True))
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if profiler is not None:
        profiler.enable()
    started = time.perf_counter()
    if clock is not None:
        clock.mark = started
    for step in scenario.steps:
        feed(slam, step)
    if clock is not None:
        clock._switch()
    elapsed = time.perf_counter() - started
    if profiler is not None:
        profiler.disable()
    return elapsed, slam.step_count


def stage_table(seed: int, particles: int, learn: bool) -> None:
    clock = StageClock()
    saved = instrument(clock)
    try:
        elapsed, steps = run(seed, particles, learn, clock)
    finally:
        for owner, name, original in saved:
            setattr(owner, name, original)
    print(f"seed {seed}, N = {particles}, noise learning {'on' if learn else 'off'}: {steps} filter steps, "
          f"{1e3 * elapsed / steps:.3f} ms per step (wall), load average {os.getloadavg()[0]:.2f}")
    print("| stage | ms per step | share |\n|---|---|---|")
    for stage, seconds in sorted(clock.seconds.items(), key=lambda kv: -kv[1]):
        print(f"| {stage} | {1e3 * seconds / steps:.3f} | {100 * seconds / elapsed:.0f} % |")


def function_table(seed: int, particles: int, learn: bool, top: int) -> None:
    profiler = cProfile.Profile()
    _, steps = run(seed, particles, learn, profiler=profiler)
    rows = [(tottime, calls, f"{filename.split('online_em_slam/')[-1]}:{line} {name}")
            for (filename, line, name), (_, calls, tottime, _, _) in pstats.Stats(profiler).stats.items()]
    print("\n| function (self time, under cProfile) | ms per step | calls per step |\n|---|---|---|")
    for tottime, calls, where in sorted(rows, reverse=True)[:top]:
        print(f"| {where} | {1e3 * tottime / steps:.3f} | {calls / steps:.1f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--learn", action="store_true", help="noise learning on (the node's default)")
    parser.add_argument("--functions", type=int, default=0, metavar="K",
                        help="also list cProfile's K most expensive functions")
    args = parser.parse_args(argv)
    stage_table(args.seed, args.particles, args.learn)
    if args.functions:
        function_table(args.seed, args.particles, args.learn, args.functions)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
