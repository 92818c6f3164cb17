"""``online-em-slam run BAG --fleet``: every robot of a fleet bag into one FleetSlam, one joint map.

A fleet bag (``online-em-slam-convert mrclam OUT --all-robots``) holds each robot's topics
under its namespace (``/robot1/control``, ``/robot1/landmark_observations``,
``/robot1/ground_truth/pose``, ...) and one survey on ``/ground_truth/landmarks``.  The
namespaces are found in the bag (``/robotK/`` prefixes of the configured input topics).
Each robot's inputs are read as a single-robot run reads them (:func:`..runner.read_inputs`
in the robot's namespace), the robots' streams merged in log-time order (ties: the robot
order) and fed through one input pipeline per robot
(:class:`online_em_slam.pipeline.fleet.FleetPipeline`: a robot's stamp checks, merge and
feeder decisions, ``filter.minimum_travel_*`` on its own travel) into
:class:`online_em_slam.core.fleet.slam.FleetSlam`.  Robot r starts at its ground-truth pose
at its first input (``--initial-pose auto`` or ``ground_truth``, as a single run from an
MRCLAM bag) and draws from ``filter.seed + r``.

Outputs in DIR: ``landmarks.csv`` (the joint map, as a single run's), per robot
``<robotK>/trajectory.csv`` (and TUM files) and ``<robotK>/noise.yaml`` (the noise it learned,
as a single run's), ``metrics.json``: the joint map scored as a single run's map
(:func:`..report.evaluate`: by id with known ids, within the match gate, shape after the rigid
fit) and under ``robots`` each robot's trajectory metrics against its own ground truth, its
drops, skipped inputs and learned noise; ``map.png`` (every robot's track).
"""
from __future__ import annotations

import heapq
import re
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import plots, report
from ..bag.bagio import absolute_topic
from ..core.config import SlamConfig
from ..pipeline import OBSERVATIONS
from ..pipeline.fleet import FleetPipeline
from .evaluation import DEFAULT_MATCH_GATE, timing_metrics
from .frames import check_frame
from .runner import (BagInputs, FailureLog, RunResult, choose_initial_pose, read_inputs, revised_trajectory,
                     truth_start)
from .tum import write_revised_tum, write_run_tum

NAMESPACE = re.compile(r"^(/robot\d+)/")


@dataclass
class FleetInputs:
    """A fleet bag's inputs: one :class:`..runner.BagInputs` per robot namespace."""

    path: str
    namespaces: list[str]
    robots: list[BagInputs]

    @property
    def names(self) -> list[str]:
        return [ns.strip("/") for ns in self.namespaces]

    def events(self, refused: list[Counter]):
        """(robot index, kind, stamp, payload, log_time) of every robot, in log-time order (ties: robot order)."""
        def tagged(r: int):
            for kind, stamp, payload, log_time in self.robots[r].events.stream(refused[r]):
                yield log_time, r, kind, stamp, payload

        streams = [tagged(r) for r in range(len(self.robots))]
        for log_time, r, kind, stamp, payload in heapq.merge(*streams, key=lambda e: (e[0], e[1])):
            yield r, kind, stamp, payload, log_time


def fleet_namespaces(bag, settings) -> list[str]:
    """The robot namespaces of ``bag`` that carry the observation topic, in robot number order."""
    from ..bag.bagio import bag_topics

    observations = absolute_topic(settings.observations_topic)
    found = {m.group(1) for topic in bag_topics(bag) if (m := NAMESPACE.match(topic))
             and topic[len(m.group(1)):] == observations}
    return sorted(found, key=lambda ns: int(ns[len("/robot"):]))


def read_fleet_inputs(bag, settings) -> FleetInputs:
    namespaces = fleet_namespaces(bag, settings)
    if not namespaces:
        raise ValueError(f"{bag}: not a fleet bag: no /robotK{absolute_topic(settings.observations_topic)} topic")
    return FleetInputs(str(bag), namespaces, [read_inputs(bag, settings, ns) for ns in namespaces])


def fleet_initial_poses(mode: str, inputs: FleetInputs, config: SlamConfig, settings, file_values: dict) -> list:
    """Each robot's start: its ground-truth pose at its first input (``auto`` or ``ground_truth``)."""
    if mode not in ("auto", "ground_truth"):
        raise ValueError(f"--fleet: --initial-pose must be auto or ground_truth (each robot at its own "
                         f"ground-truth start), got {mode!r}")
    values = {k: v for k, v in file_values.items() if not k.startswith("initial_pose.")}
    return [choose_initial_pose("ground_truth", robot, config, settings, values) for robot in inputs.robots]


class _Track:
    """One robot's record of the run: step durations, trajectory, observation messages."""

    def __init__(self) -> None:
        self.durations, self.rows, self.failures = [], [], FailureLog()
        self.first = self.last = None
        self.n_obs_msgs, self.known_ids = 0, False

    def applied(self, item, fed) -> None:
        self.failures.note(item, fed)
        if fed.report is not None:
            self.durations.append(fed.report.duration)
        if fed.trajectory_point is not None:
            self.rows.append(fed.trajectory_point)

    def pushed(self, kind: int, stamp: float, payload) -> None:
        self.first = stamp if self.first is None or stamp < self.first else self.first
        self.last = stamp if self.last is None or stamp > self.last else self.last
        self.n_obs_msgs += kind == OBSERVATIONS
        self.known_ids = self.known_ids or (kind == OBSERVATIONS and bool(np.any(payload.ids >= 0)))

    @property
    def duration(self) -> float:
        return (self.last - self.first) if self.first is not None else 0.0


def feed_fleet(fleet, inputs: FleetInputs, settings) -> tuple[list[_Track], list[Counter], FleetPipeline, float]:
    """Stream every robot's inputs through its pipeline into ``fleet``; (tracks, refused, pipeline, busy s)."""
    tracks = [_Track() for _ in inputs.robots]
    refused = [Counter() for _ in inputs.robots]
    pipeline = FleetPipeline(fleet, settings.motion_source, settings.input_delay, settings.time_jump_threshold,
                             on_applied=lambda r, item, fed: tracks[r].applied(item, fed))
    busy = 0.0
    for r, kind, stamp, payload, log_time in inputs.events(refused):
        tracks[r].pushed(kind, stamp, payload)
        started = time.perf_counter()
        pipeline.push(r, kind, stamp, payload, log_time)
        busy += time.perf_counter() - started
    started = time.perf_counter()
    pipeline.flush()
    return tracks, refused, pipeline, busy + time.perf_counter() - started


def run_fleet(inputs: FleetInputs, config: SlamConfig, settings, initial: list, output: Path, plot: bool = True,
              match_gate: float = DEFAULT_MATCH_GATE, align: bool = False, extra: dict | None = None,
              param_values: dict | None = None) -> dict:
    """Run FleetSlam on the fleet's inputs; write DIR/landmarks.csv, <robot>/trajectory.csv and noise.yaml,
    metrics.json [, map.png].  ``param_values``: the parameter file's values, the base of each noise.yaml."""
    from ..core import FleetSlam

    output.mkdir(parents=True, exist_ok=True)
    fleet = FleetSlam(config, [p.pose for p in initial])
    tracks, refused, pipeline, busy = feed_fleet(fleet, inputs, settings)
    landmarks = fleet.landmarks()
    metrics = {"method": "online_em_fleet", "bag": inputs.path, **(extra or {}), "seed": config.filter.seed,
               "num_particles": config.filter.num_particles, "motion_model": config.motion.model,
               "robots_in_fleet": inputs.names}
    per_robot, frames = {}, []
    for r, (name, robot_inputs, track) in enumerate(zip(inputs.names, inputs.robots, tracks)):
        skipped = {k: int(v) for k, v in pipeline.drops(r).items() if v}
        skipped.update({k: int(v) for k, v in refused[r].items() if v})
        published = np.asarray(track.rows, dtype=float).reshape(-1, 4)
        result = RunResult("online_em_fleet", published, landmarks, track.durations, busy, track.duration,
                           dict(fleet.robot(r).drops), skipped, track.n_obs_msgs, track.known_ids, track.failures,
                           revised_trajectory(fleet.revised_trajectory(r), published))
        frame = check_frame(initial[r], truth_start(robot_inputs, config), match_gate)
        frames.append(frame)
        scored = report.evaluate(result, robot_inputs, config, match_gate, align, frame)
        if r == 0:     # the joint map: the same for every robot
            metrics.update({k: scored[k] for k in ("n_landmarks", "n_confirmed_landmarks", "landmarks")
                            if k in scored})
        per_robot[name] = {"initial_pose": initial[r].to_dict(), "n_observation_messages": track.n_obs_msgs,
                           **{k: scored[k] for k in ("trajectory", "trajectory_revised", "frame", "drops",
                                                     "runner_skipped", "input_failures") if k in scored},
                           "noise_learned": fleet.robot(r).learned_noise()}
        robot_dir = output / name
        robot_dir.mkdir(exist_ok=True)
        report.write_trajectory(robot_dir / "trajectory.csv", result.trajectory)
        report.write_noise_params(robot_dir / "noise.yaml", fleet.robot(r).learned_noise_parameters(),
                                  param_values or {}, per_robot[name]["noise_learned"])
        write_run_tum(robot_dir, result.trajectory, (config.sensor.offset_x, config.sensor.offset_y),
                      robot_inputs.gps_times, robot_inputs.gps_xy)
        write_revised_tum(robot_dir, result.revised)
    durations = [d for track in tracks for d in track.durations]
    span = [t for track in tracks for t in (track.first, track.last) if t is not None]
    metrics["timing"] = timing_metrics(durations, (max(span) - min(span)) if span else 0.0, busy).to_dict()
    metrics["robots"] = per_robot
    report.write_landmarks(output / "landmarks.csv", landmarks)
    report.json_dump(output / "metrics.json", metrics)
    if plot:
        _plot(output / "map.png", inputs, tracks, landmarks, config)
    return metrics


def _plot(path, inputs: FleetInputs, tracks: list[_Track], landmarks, config: SlamConfig) -> None:
    """Every robot's track (NaN rows between robots break the line) over the joint map."""
    gap = np.full((1, 4), np.nan)
    rows = [np.vstack([np.asarray(t.rows, dtype=float).reshape(-1, 4), gap]) for t in tracks]
    gps = [np.vstack([r.gps_xy, gap[:, :2]]) for r in inputs.robots]
    confirmed = np.asarray(landmarks.n_obs) >= config.association.confirm_observations
    plots.plot_map(path, f"fleet ({len(tracks)} robots): {Path(inputs.path).name}", np.vstack(rows),
                   np.asarray(landmarks.positions).reshape(-1, 2), landmarks.ids, confirmed,
                   inputs.robots[0].landmarks, np.vstack(gps), (config.sensor.offset_x, config.sensor.offset_y))


def fleet_summary(metrics: dict) -> str:
    """The joint map's scores, then each robot's trajectory RMSE."""
    parts = [f"{metrics['method']} ({len(metrics['robots'])} robots):"]
    lm = metrics.get("landmarks")
    if lm:
        parts.append(f"joint map {lm['n_matched']}/{lm['n_true']} landmarks within the gate, {lm['n_spurious']} "
                     f"spurious, RMSE {report._fmt(lm['rmse'])} m (shape {report._fmt(lm.get('shape_error'))});")
    parts.append(f"{metrics['n_landmarks']} landmarks ({metrics['n_confirmed_landmarks']} confirmed);")
    for name, robot in metrics["robots"].items():
        tr, revised = robot.get("trajectory"), robot.get("trajectory_revised")
        again = f" ({report._fmt(revised['rmse'])} m as the replays filtered it again)" if revised else ""
        parts.append(f"{name} trajectory RMSE {report._fmt(tr['rmse']) if tr else 'n/a'} m{again};")
    tm = metrics["timing"]
    parts.append(f"{report._fmt(tm['mean_step_ms'], 2)} ms/step, real-time factor "
                 f"{report._fmt(tm['real_time_factor'], 1)} (wall {report._fmt(tm['wall_time_s'], 1)} s)")
    return " ".join(parts)


def cmd_run_fleet(args, config: SlamConfig, settings, file_values: dict, extra: dict) -> int:
    """``online-em-slam run BAG --fleet ...`` after the parameter files are read (cli.py)."""
    inputs = read_fleet_inputs(args.bag, settings)
    if not any(len(robot.events) for robot in inputs.robots):
        raise ValueError(f"{args.bag}: no inputs on the robots' configured topics")
    initial = fleet_initial_poses(args.initial_pose, inputs, config, settings, file_values)
    metrics = run_fleet(inputs, config, settings, initial, Path(args.output), plot=not args.no_plot,
                        match_gate=args.match_gate, align=args.align, extra=extra, param_values=file_values)
    print(fleet_summary(metrics))
    for name, robot in metrics["robots"].items():
        warning = report.failure_warning(robot, f"the fleet (robot {name})")
        if warning:
            print(warning, file=sys.stderr, flush=True)
    print(f"wrote {args.output}/landmarks.csv, metrics.json, <robot>/trajectory.csv"
          + ("" if args.no_plot else ", map.png"))
    return 0

