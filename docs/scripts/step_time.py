"""CPU time per filter step on the seed scenario, per M-step, robust to a shared machine.

    python docs/scripts/step_time.py [--seeds 0 1 2] [--particles 100]

Wall-clock step times of the benchmark inflate when other processes share the
cores; process CPU time of the same runs does much less.  Prints the mean CPU
milliseconds per filter step for the observed-information and the complete-data
M-step, and the load average it was measured under.
"""
from __future__ import annotations

import argparse
import os
import time

from online_em_slam.core import OnlineEMSlam
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for


def cpu_ms_per_step(seed: int, m_step: str, particles: int) -> float:
    scenario = simulate(ScenarioConfig(seed=seed))
    config = slam_config_for(scenario)
    config.em.m_step = m_step
    config.filter.num_particles = particles
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    started = time.process_time()
    for step in scenario.steps:
        feed(slam, step)
    return (time.process_time() - started) * 1e3 / slam.step_count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--particles", type=int, default=100)
    args = parser.parse_args()
    for m_step in ("observed", "complete"):
        times = [cpu_ms_per_step(seed, m_step, args.particles) for seed in args.seeds]
        print(f"{m_step}: {sum(times) / len(times):.3f} ms CPU per step "
              f"(seeds {args.seeds}: {', '.join(f'{t:.3f}' for t in times)})")
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
