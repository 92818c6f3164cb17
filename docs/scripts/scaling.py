"""Scaling of a filter step: against particles N, map size M, observations per scan; memory in time.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python docs/scripts/scaling.py \
        [--particles 50 100 200 500 1000] [--landmarks 233 1000 5000] [--per-scan 2 6 20 50] \
        [--corridor-cap 150] [--memory-laps 4]

Online EM with the core's defaults (observed-information M-step, no noise learning) and
known landmark ids (association out of the timings).  Wall time of each filter step (one
``feed``: control then scan), mean and p99, and the real-time factor at 10 scans per second
(100 ms / mean step time).  Four measurements:

* particles: the seed scenario (20 landmarks, 1500 steps), N = 50 ... 1000;
* map size: a straight corridor, landmarks 1 m apart alternating 1 m / 2 m left and right,
  sensor range 6.5 m (about 6 landmarks per scan), 2 m per step (2 new landmarks per step),
  N = 100; the map grows along the run and the time per step at map size M is the mean of
  the 50 steps before the map reaches M (map sizes M - 100 to M).  The run stops when the
  largest M is reached or after ``--corridor-cap`` seconds (then the largest M reached is
  printed); M = 20 is the seed scenario's N = 100 row (a full 20-landmark map);
* observations per scan: the same corridor at 1 m per step (1 new landmark per step), sensor
  range set for about 2, 6, 20, 50 landmarks per scan, 300 steps, N = 100 (the map ends near
  300 landmarks in every row);
* memory: the seed route driven ``--memory-laps`` laps (510 steps each), N = 100, under
  tracemalloc; the resident set (VmRSS) and the traced Python heap after the first lap
  and at the end, and the peaks.

The corridor scans are drawn step by step (the package's simulate() draws every
(step, landmark) pair at once, T x M, too large at M = 5000) with the simulator's
observation model and noise (scenario defaults: sigma_r 0.5 m, sigma_b 3 deg).
"""
from __future__ import annotations

import argparse
import math
import os
import time
import tracemalloc

import numpy as np

from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import ObservationNoiseConfig
from online_em_slam.core.models.angles import wrap_angle
from online_em_slam.core.models.observation import noise_covariance, predict_observation
from online_em_slam.experiments.simulation import (ScenarioConfig, SimStep, bicycle_step, feed, simulate,
                                                   slam_config_for)

SCAN_PERIOD_MS = 100.0      # 10 scans per second


def summary(times_s) -> tuple[float, float]:
    """(mean, p99) in ms."""
    ms = np.asarray(times_s) * 1e3
    return float(ms.mean()), float(np.percentile(ms, 99))


def run_seed(particles: int, seed: int = 0) -> tuple[float, float, int]:
    scenario = simulate(ScenarioConfig(seed=seed))
    slam = OnlineEMSlam(slam_config_for(scenario, num_particles=particles), initial_pose=scenario.initial_pose,
                        stamp=0.0)
    times = []
    for step in scenario.steps:
        started = time.perf_counter()
        feed(slam, step)
        times.append(time.perf_counter() - started)
    return (*summary(times), len(slam._map))


def corridor_steps(n_steps: int, step_length: float, max_range: float, seed: int = 0, offsets=(1.0, 2.0)):
    """Straight corridor along x: landmark i at x = i + 0.5, y = +-1 or +-2 m (alternating),
    the vehicle on y = 0 heading +x at step_length / dt; scans drawn one step at a time."""
    cfg = ScenarioConfig(seed=seed, max_range=max_range, speed=step_length / 0.2)
    n_landmarks = int(n_steps * step_length + max_range + 10)
    index = np.arange(n_landmarks)
    side = np.where(index % 2 == 0, 1.0, -1.0)
    landmarks = np.column_stack([index + 0.5, side * np.where((index // 2) % 2 == 0, *offsets)])
    R = noise_covariance(ObservationNoiseConfig(sigma_range=cfg.sigma_range, sigma_bearing=cfg.sigma_bearing,
                                                rho=cfg.rho), np.zeros(()))
    chol = np.linalg.cholesky(R)
    rng = np.random.default_rng(seed)
    pose = np.array([0.0, 0.0, 0.0])
    steps = []
    for k in range(n_steps):
        true_control = np.array([cfg.speed, 0.0])
        pose = bicycle_step(pose, true_control, cfg.dt, cfg.wheelbase)
        lo, hi = np.searchsorted(landmarks[:, 0], [pose[0] - max_range, pose[0] + max_range])
        near = np.arange(lo, hi)
        clean = predict_observation(pose, landmarks[near])
        seen = near[(clean[:, 0] <= max_range) & (np.abs(clean[:, 1]) <= math.pi / 2)]
        clean = predict_observation(pose, landmarks[seen])
        measured = clean + rng.standard_normal((seen.size, 2)) @ chol.T
        control = true_control + rng.standard_normal(2) * np.array([cfg.sigma_speed, cfg.sigma_steering])
        steps.append(SimStep(stamp=(k + 1) * cfg.dt, control_stamp=k * cfg.dt, control=control,
                             ranges=np.abs(measured[:, 0]), bearings=wrap_angle(measured[:, 1]),
                             ids=seen.astype(np.int64), true_ids=seen.astype(np.int64),
                             outlier=np.zeros(seen.size, dtype=bool)))
    return cfg, steps


def run_corridor(steps, cfg, particles: int, cap_s: float | None = None, stop_at: int | None = None):
    """Per-step wall times, map sizes after each step, observations per scan."""
    slam = OnlineEMSlam(slam_config_for(cfg, num_particles=particles), initial_pose=(0.0, 0.0, 0.0), stamp=0.0)
    times, sizes, seen = [], [], []
    began = time.perf_counter()
    for step in steps:
        started = time.perf_counter()
        feed(slam, step)
        times.append(time.perf_counter() - started)
        sizes.append(len(slam._map))
        seen.append(step.ids.size)
        if stop_at is not None and sizes[-1] >= stop_at:
            break
        if cap_s is not None and time.perf_counter() - began > cap_s:
            break
    return np.array(times), np.array(sizes), np.array(seen), time.perf_counter() - began


def proc_status_mb(key: str) -> float:
    """A memory line of /proc/self/status in MB (VmRSS: resident now, VmHWM: its peak)."""
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[50, 100, 200, 500, 1000])
    parser.add_argument("--landmarks", type=int, nargs="+", default=[233, 1000, 5000])
    parser.add_argument("--per-scan", type=int, nargs="+", default=[2, 6, 20, 50])
    parser.add_argument("--corridor-cap", type=float, default=150.0,
                        help="seconds after which the map-size run stops")
    parser.add_argument("--memory-laps", type=int, default=4)
    args = parser.parse_args()
    print(f"load average at start {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; "
          f"BLAS threads OMP={os.environ.get('OMP_NUM_THREADS')} OPENBLAS={os.environ.get('OPENBLAS_NUM_THREADS')}")

    print("\n## particles (seed scenario, M = 20, 1500 steps)")
    print("| N | mean ms | p99 ms | real-time factor at 10 Hz |\n|---|---|---|---|")
    for n in args.particles:
        mean, p99, _ = run_seed(n)
        print(f"| {n} | {mean:.2f} | {p99:.2f} | {SCAN_PERIOD_MS / mean:.0f} |", flush=True)

    print("\n## map size (corridor, ~6 landmarks per scan, N = 100)")
    target = max(args.landmarks)
    cfg, steps = corridor_steps(int(0.55 * target) + 50, 2.0, 6.5)     # 2 landmarks a step, some pruned
    times, sizes, seen, spent = run_corridor(steps, cfg, 100, cap_s=args.corridor_cap, stop_at=target)
    print(f"{len(times)} steps in {spent:.0f} s, map of {sizes[-1]} landmarks, "
          f"{seen.mean():.1f} observations per scan")
    print("| M | steps timed | mean ms | p99 ms | real-time factor at 10 Hz |\n|---|---|---|---|---|")
    for m in args.landmarks:
        reached = np.flatnonzero(sizes >= m)
        if reached.size == 0:
            print(f"| {m} | not reached (stopped at M = {sizes[-1]} after {spent:.0f} s) | | | |")
            continue
        end = reached[0] + 1
        window = times[max(0, end - 50):end]
        mean, p99 = summary(window)
        print(f"| {m} | {window.size} | {mean:.2f} | {p99:.2f} | {SCAN_PERIOD_MS / mean:.1f} |", flush=True)
    tail = summary(times[-50:])
    print(f"last 50 steps (M = {sizes[-50]} to {sizes[-1]}): mean {tail[0]:.2f} ms, p99 {tail[1]:.2f} ms")

    print("\n## observations per scan (corridor, 1 new landmark per step, 300 steps, N = 100)")
    print("| target per scan | sensor range m | observed per scan | mean ms | p99 ms | final M |"
          "\n|---|---|---|---|---|---|")
    for k in args.per_scan:
        max_range = k + 0.5
        cfg, steps = corridor_steps(300, 1.0, max_range)
        times, sizes, seen, _ = run_corridor(steps, cfg, 100)
        mean, p99 = summary(times[50:])
        print(f"| {k} | {max_range:.1f} | {seen[50:].mean():.1f} | {mean:.2f} | {p99:.2f} | {sizes[-1]} |",
              flush=True)

    print(f"\n## memory (seed route, {args.memory_laps} laps, N = 100, tracemalloc on)")
    scenario = simulate(ScenarioConfig(seed=0, laps=args.memory_laps))
    slam = OnlineEMSlam(slam_config_for(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
    tracemalloc.start()
    lap = int(scenario.lap_ends[0]) if len(scenario.lap_ends) else 500
    print("| after step | VmRSS MB | traced heap MB | traced peak MB |\n|---|---|---|---|")
    for k, step in enumerate(scenario.steps, start=1):
        feed(slam, step)
        if k == 10 or k % lap == 0 or k == len(scenario.steps):
            current, peak = tracemalloc.get_traced_memory()
            print(f"| {k} | {proc_status_mb('VmRSS'):.1f} | {current / 2**20:.2f} | {peak / 2**20:.2f} |", flush=True)
    tracemalloc.stop()
    print(f"process peak RSS (VmHWM, the whole script) {proc_status_mb('VmHWM'):.1f} MB")
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
