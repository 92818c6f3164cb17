"""Monte Carlo benchmark of the seed paper's simulated experiment.

    online-em-slam-benchmark --runs 20 --particles 100 --output results/benchmark
    online-em-slam-benchmark --runs 20 --laps 1 3 10 --output results/laps
    online-em-slam-benchmark --runs 20 --laps 1 3 10 --set em.m_step=observed --tag observed \\
        --output results/laps --compare-with results/laps/results.json

For each seeded replication of the simulator, every method runs on the same
inputs: online EM and Block Online EM with the default observed-information
M-step (``online_em``, ``boem``), the seed's complete-data M-step with each
smoother and block variant (``*_complete*``), marginal-SLAM, FastSLAM 2.0,
EKF-SLAM, and the GTSAM batch maximum-likelihood
reference (skipped with a note when gtsam is not installed).  Every method is
scored by its landmark RMSE and its split into *shape* (RMSE after the best
rigid 2-D fit of the estimated map onto the truth) and *frame*
(sqrt(RMSE^2 - shape^2)); see :func:`online_em_slam.offline.evaluation.map_error_split`.

* Seed run (default): prints a table and writes ``results.json``, ``table.md``
  and ``landmark_error.png`` (mean landmark error against time, the seed's figure 2).
* ``--laps L1 L2 ...``: the closed route driven max(L) times (``ScenarioConfig.laps``,
  fresh noise every lap); the online methods are scored after every lap of one
  long run (an L-lap run is the exact prefix of a longer one), GTSAM is solved
  once per requested L.  Writes ``results.json``, ``table.md`` and
  ``laps_error.png`` (RMSE, shape, frame against laps, mean +- standard error).
* ``--set section.key=value`` (repeatable) overrides the online-EM methods'
  configuration (after the method's own smoother / algorithm); the baselines
  keep the scenario's configuration and stay a fixed reference.
* ``--tag NAME`` names the output files (``results-NAME.json`` ...) so variants
  share a directory; ``--compare-with FILE`` prints the paired differences
  (this run - FILE, same method, laps and seed) and ``--compare A B`` does it
  for two existing files without running anything.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..core import OnlineEMSlam, SlamConfig
from ..core.models.angles import wrap_angle
from ..offline.evaluation import landmark_pairs_by_id, map_error_split
from .simulation import Scenario, ScenarioConfig, feed, simulate, slam_config_for

from .benchmark_tables import compare_files, format_laps_table, format_table, plot_curves, plot_laps, summarize
from .methods import ALL_METHODS, ONLINE_METHODS

@dataclass
class RunResult:
    method: str
    seed: int
    landmark_rmse: float
    shape_error: float
    frame_error: float
    pose_rmse: float
    mean_step_ms: float
    p99_step_ms: float
    mean_nees: float
    mean_true_pose_loglik: float
    n_landmarks: int
    error_curve: list[float]
    laps: int | None = None          # laps driven when scored; None for the seed run
    n_steps: int = 0

    def to_dict(self) -> dict:
        return self.__dict__.copy()


# --------------------------------------------------------------------------- configuration

def parse_override(text: str) -> tuple[str, str, object]:
    """``section.key=value`` -> (section, key, value); the value is read as YAML
    (``25`` -> int, ``0.5`` -> float, ``observed`` -> str, ``[0.9, 0.1]`` -> list)."""
    import yaml
    name, sep, value = text.partition("=")
    section, dot, key = name.strip().partition(".")
    if not sep or not dot or not section or not key:
        raise ValueError(f"--set expects section.key=value, got {text!r}")
    return section, key, yaml.safe_load(value)


def apply_overrides(config: SlamConfig, overrides: list[str] | tuple[str, ...]) -> SlamConfig:
    """Copy of ``config`` with the ``section.key=value`` overrides, validated
    (unknown sections / keys and out-of-range values raise ValueError)."""
    if not overrides:
        return config
    data = config.to_dict()
    for text in overrides:
        section, key, value = parse_override(text)
        if section not in data:
            raise ValueError(f"--set {text!r}: unknown section {section!r}")
        data[section][key] = value
    return SlamConfig.from_dict(data)


def make_estimator(method: str, config: SlamConfig, scenario: Scenario, overrides=()):
    if method in ONLINE_METHODS:
        options = ONLINE_METHODS[method]
        config.em.m_step = options["m_step"]
        config.filter.smoother = options["smoother"]
        config.em.algorithm = options["algorithm"]
        config = apply_overrides(config, overrides)
        return OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if method == "marginal_slam":
        from ..baselines.marginal_slam import MarginalSlam
        config.filter.smoother = "forward"
        config = apply_overrides(config, overrides)
        return MarginalSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if method == "fastslam2":
        from ..baselines.fastslam2 import FastSlam2
        return FastSlam2(config, initial_pose=scenario.initial_pose, stamp=0.0)
    if method == "ekf_slam":
        from ..baselines.ekf_slam import EkfSlam
        return EkfSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(ALL_METHODS)}")


# --------------------------------------------------------------------------- one run

def landmark_errors(ids: np.ndarray, positions: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean error of each estimated landmark whose id indexes the true landmarks."""
    estimated, true = landmark_pairs_by_id(ids, positions, truth)
    return np.linalg.norm(estimated - true, axis=1)


def map_scores(ids: np.ndarray, positions: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """Landmark RMSE, shape and frame error of a map matched to the truth by id."""
    return tuple(float(v) for v in map_error_split(*landmark_pairs_by_id(ids, positions, truth)))


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


@dataclass
class StepLog:
    """Per-step records of a run, scored on any prefix (for the lap checkpoints)."""

    durations: list[float] = field(default_factory=list)
    pose_sq: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    loglik: list[float] = field(default_factory=list)
    curve: list[float] = field(default_factory=list)

    def record(self, estimator, truth: np.ndarray, seconds: float) -> None:
        estimate = estimator.pose()
        self.durations.append(seconds)
        self.pose_sq.append(float(np.sum((estimate.mean[:2] - truth[:2]) ** 2)))
        nees, loglik = pose_consistency(estimate.mean, estimate.covariance, truth)
        self.nees.append(nees)
        self.loglik.append(loglik)

    def result(self, method: str, seed: int, estimator, truth: np.ndarray, laps: int | None) -> RunResult:
        lm = estimator.landmarks()
        ms = 1e3 * np.asarray(self.durations)
        return RunResult(method, seed, *map_scores(lm.ids, lm.positions, truth),
                         float(np.sqrt(np.mean(self.pose_sq))), float(ms.mean()), float(np.percentile(ms, 99)),
                         float(np.nanmean(self.nees)), float(np.nanmean(self.loglik)), int(len(lm)),
                         list(self.curve), laps, len(ms))


def run_online(method: str, scenario: Scenario, particles: int, seed: int, overrides=(),
               checkpoints: dict[int, int] | None = None) -> list[RunResult]:
    """Run one method over the scenario; scored at the end, or after each step
    count in ``checkpoints`` (step count -> laps driven).  The per-step landmark
    error curve (the seed's figure 2) is kept for the seed run only."""
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    estimator = make_estimator(method, config, scenario, overrides)
    log, results = StepLog(), []
    for k, step in enumerate(scenario.steps):
        started = time.perf_counter()
        feed(estimator, step)
        log.record(estimator, scenario.true_poses[k + 1], time.perf_counter() - started)
        if checkpoints is None:
            lm = estimator.landmarks()
            errors = landmark_errors(lm.ids, lm.positions, scenario.landmarks)
            log.curve.append(float(np.sqrt(np.mean(errors ** 2))) if errors.size else math.nan)
        elif k + 1 in checkpoints:
            results.append(log.result(method, seed, estimator, scenario.landmarks, checkpoints[k + 1]))
    if checkpoints is None:
        results.append(log.result(method, seed, estimator, scenario.landmarks, None))
    return results


def run_gtsam(scenario: Scenario, particles: int, seed: int, laps: int | None = None) -> RunResult | None:
    from ..baselines.gtsam_batch import batch_estimate
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    started = time.perf_counter()
    try:
        result = batch_estimate(scenario, config)
    except ImportError:
        return None
    elapsed = time.perf_counter() - started
    poses, landmarks = result.poses, result.landmarks
    scores = map_scores(np.arange(len(landmarks)), landmarks, scenario.landmarks)   # unseen rows are NaN
    pose_err = np.sum((poses[1:, :2] - scenario.true_poses[1:, :2]) ** 2, axis=1)
    per_step = 1e3 * elapsed / scenario.n_steps
    return RunResult("gtsam_batch", seed, *scores, float(np.sqrt(np.mean(pose_err))),
                     per_step, per_step, math.nan, math.nan, int(len(landmarks)), [], laps, scenario.n_steps)


@dataclass(frozen=True)
class Job:
    """One method on one seed (picklable for the worker processes)."""

    method: str
    seed: int
    particles: int
    steps: int
    laps: tuple[int, ...] = ()          # empty: the seed run of ``steps`` steps
    overrides: tuple[str, ...] = ()


def run_one(job: Job) -> list[dict]:
    """Results (as dicts) of one job: one row, or one per lap with ``laps``."""
    if job.method == "gtsam_batch":
        runs = [(simulate(ScenarioConfig(seed=job.seed, n_steps=job.steps, laps=laps)), laps or None)
                for laps in (job.laps or (0,))]
        results = [run_gtsam(scenario, job.particles, job.seed, laps) for scenario, laps in runs]
        return [r.to_dict() for r in results if r is not None]
    if not job.laps:
        scenario = simulate(ScenarioConfig(seed=job.seed, n_steps=job.steps))
        return [r.to_dict() for r in run_online(job.method, scenario, job.particles, job.seed, job.overrides)]
    scenario = simulate(ScenarioConfig(seed=job.seed, laps=max(job.laps)))
    checkpoints = {int(end): lap for lap, end in enumerate(scenario.lap_ends, start=1)}
    return [r.to_dict() for r in run_online(job.method, scenario, job.particles, job.seed, job.overrides,
                                            checkpoints)]


# --------------------------------------------------------------------------- summaries

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


def run_em_passes(scenario: Scenario, particles: int, seed: int, passes: int, overrides=()) -> list[float]:
    """Landmark RMSE after each of ``passes`` passes of complete-data online EM (forward smoother)
    over the same data, each pass starting from the previous pass's map: batch
    EM iterations, which show how far one online pass is from the EM fixed point."""
    config = slam_config_for(scenario, num_particles=particles, seed=seed)
    estimator = make_estimator("online_em_complete_forward", config, scenario, overrides)
    rmse = []
    for index in range(passes):
        if index:
            estimator.start_new_pass(scenario.initial_pose, stamp=0.0)
        for step in scenario.steps:
            feed(estimator, step)
        lm = estimator.landmarks()
        rmse.append(float(np.sqrt(np.mean(landmark_errors(lm.ids, lm.positions, scenario.landmarks) ** 2))))
    return rmse


def em_passes_job(job: tuple) -> list[float]:
    seed, particles, steps, passes, overrides = job
    return run_em_passes(simulate(ScenarioConfig(seed=seed, n_steps=steps)), particles, seed, passes, overrides)


def em_passes_main(args) -> int:
    """``--em-passes K``: mean landmark RMSE after each pass, written to em_passes.json."""
    jobs = [(seed, args.particles, args.steps, args.em_passes, tuple(args.set)) for seed in range(args.runs)]
    curves = np.array(_pool_map(em_passes_job, jobs, args.jobs))                      # (runs, K)
    lines = ["| pass | landmark RMSE mean (m) | median | std |", "|---|---|---|---|"]
    for k in range(args.em_passes):
        column = curves[:, k]
        lines.append(f"| {k + 1} | {column.mean():.3f} | {np.median(column):.3f} | {column.std(ddof=1) if len(column) > 1 else 0.0:.3f} |")
    text = "\n".join(lines)
    print(text)
    path = output_path(args, "em_passes", "json")
    with open(path, "w") as handle:
        json.dump({"meta": {"runs": args.runs, "particles": args.particles, "steps": args.steps,
                            "passes": args.em_passes, "overrides": args.set, "tag": args.tag},
                   "rmse_per_pass": curves.tolist(), "mean": curves.mean(axis=0).tolist()}, handle, indent=1)
    print(f"wrote {path}")
    return 0


def output_path(args, name: str, extension: str) -> str:
    """``OUTPUT/name.ext``, or ``OUTPUT/name-TAG.ext`` with ``--tag``."""
    return os.path.join(args.output, f"{name}-{args.tag}.{extension}" if args.tag else f"{name}.{extension}")


def run_jobs(args) -> list[dict]:
    jobs = [Job(m, s, args.particles, args.steps, tuple(sorted(set(args.laps or ()))), tuple(args.set))
            for s in range(args.runs) for m in args.methods]
    if args.jobs > 1:
        return [row for rows in _pool_map(run_one, jobs, args.jobs) for row in rows]
    results = []
    for i, job in enumerate(jobs, 1):
        results.extend(run_one(job))
        print(f"\r{i}/{len(jobs)} {job.method} seed {job.seed}", end="", flush=True)
    print()
    return results


def write_outputs(args, results: list[dict], wall_time: float) -> str:
    """Print the table and write results / table / figure; returns the results path."""
    table = summarize(results)
    text = format_laps_table(table, args.laps) if args.laps else format_table(table)
    print(text)
    meta = {"runs": args.runs, "particles": args.particles, "steps": None if args.laps else args.steps,
            "laps": args.laps, "overrides": args.set, "tag": args.tag, "methods": args.methods,
            "wall_time_s": wall_time, "cpu_count": os.cpu_count(),
            "date": time.strftime("%Y-%m-%d"),
            "scores": "landmark RMSE matched by id; shape = RMSE after the best rigid 2-D fit onto the truth; "
                      "frame = sqrt(RMSE^2 - shape^2)"}
    paths = [output_path(args, "results", "json"), output_path(args, "table", "md"),
             output_path(args, "laps_error" if args.laps else "landmark_error", "png")]
    with open(paths[0], "w") as handle:
        json.dump({"meta": meta, "summary": table, "runs": results}, handle, indent=1)
    with open(paths[1], "w") as handle:
        handle.write(text + "\n")
    if args.laps:
        plot_laps(table, paths[2], " ".join([args.tag] + args.set))
    else:
        plot_curves(results, paths[2], ScenarioConfig().dt)
    print("wrote " + ", ".join(paths))
    return paths[0]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--runs", type=int, default=20, help="Monte Carlo replications (seeds 0..runs-1)")
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--steps", type=int, default=1500, help="simulated steps per run (seed run)")
    parser.add_argument("--laps", type=int, nargs="+", metavar="L",
                        help="long-run experiment: drive the closed route L times (scored after each lap)")
    parser.add_argument("--methods", nargs="+", default=list(ALL_METHODS), choices=ALL_METHODS)
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override of the online-EM configuration (repeatable), e.g. em.m_step=observed")
    parser.add_argument("--tag", default="", help="name of this variant: output files get a -TAG suffix")
    parser.add_argument("--compare-with", metavar="FILE",
                        help="after the run, paired differences against another results JSON (same seeds)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"),
                        help="only print the paired differences B - A of two results JSON files")
    parser.add_argument("--jobs", type=int, default=1,
                        help="worker processes (timings are honest with jobs <= cores)")
    parser.add_argument("--output", default="results/benchmark")
    parser.add_argument("--em-passes", type=int, default=0, metavar="K",
                        help="instead of the comparison, run K passes of online EM over each run's data "
                             "(batch EM iterations) and report the landmark RMSE after each pass")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.compare:
        print(compare_files(*args.compare))
        return 0
    if args.laps and min(args.laps) < 1:
        parser.error("--laps: lap counts must be >= 1")
    try:
        apply_overrides(slam_config_for(ScenarioConfig()), args.set)     # fail before hours of runs
    except ValueError as error:
        parser.error(str(error))
    os.makedirs(args.output, exist_ok=True)
    if args.em_passes > 0:
        return em_passes_main(args)
    started = time.perf_counter()
    results = run_jobs(args)
    path = write_outputs(args, results, time.perf_counter() - started)
    if args.compare_with:
        print()
        print(compare_files(args.compare_with, path))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
