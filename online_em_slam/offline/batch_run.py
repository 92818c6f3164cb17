"""``online-em-slam run BAG --method batch``: the batch reference on a bag, as a run.

The estimator's model solved in full (offline/batch.py; docs/METHOD.md, "The batch reference")
on the inputs the runner reads, from the same initial pose, returned as a
:class:`~.runner.RunResult` so that it is scored and written as any method's run:
trajectory.csv (a pose per scan the estimator filters), landmarks.csv (no covariances: the
batch computes no marginals), metrics.json, map.png.  Known ids only: its landmarks are the
observations' ids.  Needs gtsam.
"""
from __future__ import annotations

import time
from collections import Counter

import numpy as np

from ..core.config import SlamConfig
from ..core.types import LandmarkMap
from .batch import collect_problem, released_events, solve_problem


def batch_run(inputs, config: SlamConfig, initial_pose) -> "RunResult":
    """The batch optimum of ``inputs`` (a runner BagInputs) under ``config``, started at ``initial_pose``."""
    from .runner import RunResult

    started = time.perf_counter()
    problem = collect_problem(released_events(inputs), config, inputs.motion_source)
    if not problem.obs_id.size:
        raise ValueError(f"{inputs.path}: the batch needs observations with landmark ids; none carries one")
    result = solve_problem(problem, config, initial_pose, init="incremental")
    wall = time.perf_counter() - started
    ids, counts = np.unique(problem.obs_id, return_counts=True)
    m = result.landmark_ids.size
    landmarks = LandmarkMap(ids=result.landmark_ids, positions=result.landmarks,
                            covariances=np.full((m, 2, 2), np.nan),
                            n_obs=counts[np.searchsorted(ids, result.landmark_ids)], confirmed=np.ones(m, dtype=bool))
    skipped = Counter(result.skipped) + Counter(inputs.refused)
    return RunResult("batch", np.column_stack([result.stamps, result.poses]), landmarks, [], wall,
                     float(problem.stamps[-1] - problem.stamps[0]), {}, {k: int(v) for k, v in skipped.items()},
                     int(np.unique(problem.obs_pose).size), known_ids=True)
