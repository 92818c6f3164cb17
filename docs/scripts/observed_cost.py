"""Cost of the observed-information M-step per segment, against the map size M, in both forms.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python docs/scripts/observed_cost.py \
        [--landmarks 20 233 1000] [--segment 10] [--observed 6] [--forms covariance information]

Builds the map's Gaussian (``em.map_form``: ObservedCovariance or ObservedInformation) over
M landmarks, feeds segments of K steps with a few observations each, and times
close_segment (linearise, fold the segment in: its poses integrated out), solve (the mean;
Cholesky in information form) and the marginal covariances; prints the best of several
repeats (robust to a shared CPU) and writes a JSON next to the benchmark results.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from online_em_slam.core.config import SensorConfig
from online_em_slam.core.em.observed_covariance import ObservedCovariance
from online_em_slam.core.em.observed_information import ObservedInformation
from online_em_slam.core.em.segment_factors import StepFactors

FORMS = {"covariance": ObservedCovariance, "information": ObservedInformation}


def _segment(rng, poses, m, observed):
    steps = []
    for pose in poses:
        rows = rng.choice(m, size=min(observed, m), replace=False)
        F = np.eye(3)
        F[:2, 2] = rng.normal(0, 0.5, 2)
        steps.append(StepFactors(pose, F, rng.normal(0, 0.01, 3), np.diag([1 / 400.0, 1 / 400.0, 1 / 4e4]), rows,
                                 np.column_stack([rng.uniform(2, 30, rows.size), rng.uniform(-1, 1, rows.size)]),
                                 np.broadcast_to(np.diag([4.0, 1000.0]), (rows.size, 2, 2)).copy()))
    return steps


def best_time(fn, repeats):
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return min(times) * 1e3


def measure(form: str, m: int, segment: int, observed: int, repeats: int = 15) -> dict:
    rng = np.random.default_rng(0)
    theta = rng.uniform(-100, 100, (m, 2))
    system = FORMS[form](SensorConfig(), np.zeros(3), np.zeros(3))
    system.add_landmarks(m)
    poses = np.column_stack([np.linspace(0, 10, segment), np.zeros(segment), np.zeros(segment)])
    for _ in range(3):                       # a stored system with every landmark informed
        for step in _segment(rng, poses, m, m):
            system.add_step(step)
        system.close_segment(theta)

    def close():
        for step in _segment(rng, poses, m, observed):
            system.add_step(step)
        system.close_segment(theta)

    def covariances():
        system._covariance_cache = None          # information form: made again
        system.landmark_covariances()

    close_ms = best_time(close, repeats)
    solve_ms = best_time(system.solve, repeats)
    cov_ms = best_time(covariances, max(3, repeats // 3))
    return {"form": form, "landmarks": m, "segment_length": segment, "observations_per_step": observed,
            "close_segment_ms": close_ms, "solve_ms": solve_ms, "marginal_covariances_ms": cov_ms,
            "per_step_amortised_ms": (close_ms + solve_ms) / segment}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--landmarks", type=int, nargs="+", default=[20, 233, 1000])
    parser.add_argument("--forms", nargs="+", default=list(FORMS), choices=list(FORMS))
    parser.add_argument("--segment", type=int, default=10)
    parser.add_argument("--observed", type=int, default=6)
    parser.add_argument("--output", default="docs/observed_cost.json")
    args = parser.parse_args()
    rows = [measure(form, m, args.segment, args.observed) for form in args.forms for m in args.landmarks]
    for row in rows:
        print(f"{row['form']:11s} M = {row['landmarks']:4d}: close_segment {row['close_segment_ms']:.2f} ms, solve "
              f"{row['solve_ms']:.2f} ms, marginal covariances {row['marginal_covariances_ms']:.2f} ms; "
              f"amortised over K = {row['segment_length']}: {row['per_step_amortised_ms']:.3f} ms per step")
    with open(args.output, "w") as handle:
        json.dump(rows, handle, indent=1)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
