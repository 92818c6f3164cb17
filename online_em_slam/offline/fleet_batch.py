"""The GTSAM batch optimum over every robot of a fleet bag, known ids: the fleet run's reference.

    python -m online_em_slam.offline.fleet_batch BAG --params FILE [--params FILE ...] --output DIR
                                                 [--noise-from FLEET_RUN_DIR]

Each robot's inputs are read and released as for a fleet run (:mod:`.fleet_runner`: its namespace,
its input path) and collected into the single-robot batch problem
(:func:`.batch.collect_problem`: the estimator's motion bookkeeping, its scans, its noise), with
that robot's configuration: the parameter files, and with ``--noise-from`` the noise that robot
learned in a fleet run (``FLEET_RUN_DIR/robotK/noise.yaml``, as the MRCLAM benchmark's ``(L)``
batch uses a single run's).  The problems are put end to end, one chain of pose variables per
robot (a prior at its ground-truth start, no motion factor between robots), sharing the landmark
variables, and solved as one (:func:`.batch.solve_problem`, iSAM2 initial guess, then
Levenberg-Marquardt).  DIR gets ``landmarks.csv`` (id, x, y), ``robotK/trajectory.csv`` and
``metrics.json``: the joint map scored as a fleet run's and each robot's trajectory RMSE.

Robot-to-robot reads (``reads`` of :func:`fleet_batch`, ``--robot-reads`` of a data set's
front end such as ``python -m online_em_slam.datasets.mrclam.fleet_batch``) join the problem as
bearing-range factors between the two robots' poses at the read's time (:mod:`.robot_reads`: a
pose variable added there, reads gated at ``--read-gate`` after a first solve); ``metrics.json``
counts them under ``robot_reads``.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from . import report
from .batch import InputsProblem, collect_problem, released_events, solve_problem
from .evaluation import DEFAULT_MATCH_GATE, sensor_points, trajectory_metrics
from .fleet_runner import FleetInputs, fleet_initial_poses, read_fleet_inputs
from .robot_reads import DEFAULT_READ_GATE, FleetReads, gtsam_factors, read_factors, squared_distances


def end_to_end(problems: list[InputsProblem]) -> InputsProblem:
    """The robots' problems as one: pose variables in robot order, one chain each (a placeholder
    motion into each later robot's first pose, never used: no between factor into a chain start)."""
    sizes = [len(p.stamps) for p in problems]
    if not all(sizes):
        raise ValueError("a robot of the fleet has no pose variable (no motion input before its scans)")
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
    increments, covariances = [problems[0].increments], [problems[0].motion_covariances]
    for p in problems[1:]:
        increments += [np.zeros((1, 3)), p.increments]
        covariances += [np.eye(3)[None], p.motion_covariances]
    skipped = sum((p.skipped for p in problems), Counter())
    return InputsProblem(np.concatenate([p.stamps for p in problems]), np.concatenate(increments),
                         np.concatenate(covariances),
                         np.concatenate([p.obs_pose + o for p, o in zip(problems, offsets)]),
                         np.concatenate([p.obs_id for p in problems]), np.concatenate([p.obs_y for p in problems]),
                         np.concatenate([p.obs_R for p in problems]), skipped, tuple(int(o) for o in offsets))


def robot_configs(params: list[str], names: list[str], noise_from: str | None) -> tuple[list, object, dict]:
    """(config per robot, settings, the files' values): the parameter files, then the robot's learned noise."""
    from ..parameters.yaml_file import config_from_params, load_params
    values: dict = {}
    for path in params:
        values.update(load_params(path))
    config, settings = config_from_params(values)
    configs = []
    for name in names:
        noise = Path(noise_from) / name / "noise.yaml" if noise_from else None
        if noise is not None and not noise.is_file():
            raise FileNotFoundError(f"{noise}: no learned noise of {name} (run --fleet writes it)")
        configs.append(config if noise is None else config_from_params({**values, **load_params(noise)})[0])
    return configs, settings, values


def fleet_batch(inputs: FleetInputs, configs: list, settings, initial_poses, max_iterations: int = 100,
                reads: FleetReads | None = None, read_gate: float = DEFAULT_READ_GATE):
    """(InputsBatchResult over all robots, the robots' pose variable ranges, the read factors used or
    None).  With ``reads``: a pose variable at each read's time, a factor per read, solved with
    every read, then again without those beyond ``read_gate`` (the batch's noise is Gaussian)."""
    extra = [reads.stamps_of(r) if reads is not None else () for r in range(len(inputs.robots))]
    problems = [collect_problem(released_events(robot), cfg, settings.motion_source, extra_poses=stamps)
                for robot, cfg, stamps in zip(inputs.robots, configs, extra)]
    problem = end_to_end(problems)
    ends = list(problem.chain_starts[1:]) + [len(problem.stamps)]
    chains = [slice(a, b) for a, b in zip(problem.chain_starts, ends)]

    def solve(factors):
        extra_factors = None if factors is None else (lambda gtsam: gtsam_factors(gtsam, factors, configs[0].sensor))
        return solve_problem(problem, configs[0], initial_poses, max_iterations, init="incremental",
                             extra_factors=extra_factors)

    if reads is None:
        return solve(None), chains, None
    factors = read_factors(reads, problems, problem.chain_starts, configs)
    first = solve(factors)
    sensor = configs[0].sensor
    kept = factors.subset(squared_distances(first.poses, factors, (sensor.offset_x, sensor.offset_y,
                                                                   sensor.offset_yaw)) <= read_gate, "gated")
    return (first if len(kept) == len(factors) else solve(kept)), chains, kept


def main(argv=None, reads_from=None, prog: str = "python -m online_em_slam.offline.fleet_batch") -> int:
    """The command line; ``reads_from(source, inputs) -> FleetReads``, a data set's reader of the
    robot-to-robot reads, adds ``--robot-reads SOURCE`` (required) and ``--read-gate``."""
    parser = argparse.ArgumentParser(prog=prog,
                                     description="GTSAM batch optimum over every robot of a fleet bag (known ids).")
    parser.add_argument("bag")
    parser.add_argument("--params", required=True, action="append")
    parser.add_argument("--output", required=True)
    parser.add_argument("--noise-from", default=None, help="a run --fleet output: each robot's learned noise")
    parser.add_argument("--match-gate", type=float, default=DEFAULT_MATCH_GATE)
    if reads_from is not None:
        parser.add_argument("--robot-reads", required=True, metavar="DATASET",
                            help="the data set the bag was converted from: its robot-to-robot reads as factors")
        parser.add_argument("--read-gate", type=float, default=DEFAULT_READ_GATE,
                            help="squared Mahalanobis distance beyond which a read is left out after a first solve")
    args = parser.parse_args(argv)
    try:
        return _run(args, reads_from)
    except (FileNotFoundError, ValueError) as error:
        print(f"fleet_batch: error: {error}", file=sys.stderr)
        return 1


def _run(args, reads_from=None) -> int:
    _, settings, _ = robot_configs(args.params, [], None)
    inputs = read_fleet_inputs(args.bag, settings)
    reads = reads_from(args.robot_reads, inputs) if reads_from is not None else None
    metrics = solve_and_score(inputs, args.params, args.noise_from, Path(args.output), args.match_gate, reads,
                              getattr(args, "read_gate", DEFAULT_READ_GATE))
    print(batch_summary(metrics))
    return 0


def solve_and_score(inputs: FleetInputs, params: list[str], noise_from: str | None, out: Path,
                    match_gate: float, reads: FleetReads | None = None,
                    read_gate: float = DEFAULT_READ_GATE) -> dict:
    """The batch over the fleet's robots (each robot's learned noise from ``noise_from``, else the
    files'; the robot-to-robot ``reads`` as factors when given), written to ``out`` (landmarks.csv,
    robotK/trajectory.csv, metrics.json); its metrics."""
    started = time.perf_counter()
    configs, settings, values = robot_configs(params, inputs.names, noise_from)
    initial = fleet_initial_poses("ground_truth", inputs, configs[0], settings, values)
    result, chains, factors = fleet_batch(inputs, configs, settings, [p.pose for p in initial], reads=reads,
                                          read_gate=read_gate)
    out.mkdir(parents=True, exist_ok=True)
    np.savetxt(out / "landmarks.csv", np.column_stack([result.landmark_ids, result.landmarks]),
               fmt=["%d", "%.6f", "%.6f"], delimiter=",", header="id,x,y", comments="")
    offset = (configs[0].sensor.offset_x, configs[0].sensor.offset_y)
    robots = {}
    for name, robot, chain in zip(inputs.names, inputs.robots, chains):
        trajectory = np.column_stack([result.stamps[chain], result.poses[chain]])
        (out / name).mkdir(exist_ok=True)
        report.write_trajectory(out / name / "trajectory.csv", trajectory)
        points = sensor_points(result.poses[chain], offset)
        robots[name] = {"trajectory": trajectory_metrics(result.stamps[chain], points, robot.gps_times,
                                                         robot.gps_xy).to_dict()}
    lm = report.scored_landmarks(result.landmarks, result.landmark_ids, inputs.robots[0], match_gate, by_id=True)
    metrics = {"method": "batch_fleet", "bag": inputs.path, "params": " + ".join(str(p) for p in params),
               "noise": f"learned ({noise_from})" if noise_from else "params",
               "robots_in_fleet": inputs.names, "n_landmarks": int(len(result.landmark_ids)),
               "landmarks": lm.to_dict(), "robots": robots,
               "batch": {"iterations": result.iterations, "initial_error": result.initial_error,
                         "final_error": result.final_error, "n_observations": result.n_observations,
                         "skipped": {k: int(v) for k, v in result.skipped.items()}},
               "timing": {"wall_time_s": time.perf_counter() - started, "solve_time_s": result.solve_time}}
    if factors is not None:
        metrics["robot_reads"] = reads_metrics(reads, factors, read_gate, inputs.names)
    report.json_dump(out / "metrics.json", metrics)
    return metrics


def reads_metrics(reads: FleetReads, factors, read_gate: float, names: list[str]) -> dict:
    """The robot-to-robot reads in the bag's span, those used (per observing robot) and those left
    out, by reason; the dataset's others, not in the bag (by reason)."""
    used_by = np.bincount(reads.observer[factors.read], minlength=len(names))
    return {"in_the_bag": len(reads), "used": len(factors), "read_gate": read_gate,
            "left_out": {k: int(v) for k, v in factors.left_out.items()},
            "not_in_the_bag": {k: int(v) for k, v in reads.not_in_the_bag.items()},
            "used_by_observer": {name: int(n) for name, n in zip(names, used_by)}}


def batch_summary(metrics: dict) -> str:
    d = metrics["landmarks"]
    robots = metrics["robots"]
    reads = metrics.get("robot_reads")
    with_reads = f", {reads['used']} robot-to-robot reads" if reads else ""
    return (f"batch_fleet ({len(robots)} robots, {metrics['noise']} noise{with_reads}): joint map "
            f"{d['n_matched']}/{d['n_true']} within the gate, {d['n_spurious']} spurious, shape {d['shape_error']:.3f} m; "
            + "; ".join(f"{n} trajectory RMSE {r['trajectory']['rmse']:.3f} m" for n, r in robots.items()))


if __name__ == "__main__":
    sys.exit(main())
