"""All five robots of a UTIAS MRCLAM dataset as one ROS 2 bag, one namespace per robot.

Command line (through ``online-em-slam-convert``)::

    online-em-slam-convert mrclam OUTPUT --data-dir DIR_OR_ARCHIVE --all-robots [--seconds S]
                           [--unknown-ids] [--storage mcap|sqlite3] [--overwrite] [--no-progress]

Each robot is converted as the single-robot converter does it
(:func:`~online_em_slam.datasets.mrclam.convert.mrclam_streams` and its message
factory, unchanged); its topics are moved under ``/robotK`` (``/robot1/control``,
``/robot1/odom``, ``/robot1/tf``, ``/robot1/tf_static``, ``/robot1/ground_truth/pose``,
``/robot1/ground_truth/position``, ``/robot1/landmark_observations``), as a node in
namespace ``robotK`` with nav2's ``/tf -> tf`` remapping reads them.  Frame ids stay
as in the single-robot bag.  The surveyed landmarks are written once, on
``/ground_truth/landmarks`` (no namespace: one survey for the fleet).  Messages of all
robots are merged in stamp order (ties: the single-robot topic order, then the robot).

The dataset's clock is shared by the robots; ``--seconds`` keeps the first S seconds
from each robot's first odometry sample (the same instant for every robot of a dataset).

Robot-to-robot barcode reads (subjects 1-5) are not landmarks and are dropped, as in
the single-robot bag; :func:`fleet_report_lines` counts them per robot.  The fleet batch
reads them from the dataset itself (:mod:`.fleet_batch`, ``--robot-reads``).  The survey's
label correction (:mod:`.survey`) is found from every robot's measurements: the one
correction the robots that find any agree on (the most common when they differ).
"""
from __future__ import annotations

import heapq
from collections import Counter
from dataclasses import replace
from pathlib import Path

from ...bag.bagio import clear_bag_directory, jazzy_typestore, write_topics
from ..kth.convert import TOPIC_GT_LANDMARKS, TOPIC_TF_STATIC
from .convert import (MSGTYPES, TOPIC_PRIORITY, MrclamStreams, convert_cli, fail, iter_messages, mrclam_streams,
                      report_lines)
from .dataset import ROBOTS, MrclamRun, load_mrclam

#: Topics written once for the fleet (not per robot).
FLEET_TOPICS = (TOPIC_GT_LANDMARKS,)


def namespace(robot: int) -> str:
    return f"/robot{int(robot)}"


def robot_topic(robot: int, topic: str) -> str:
    """The fleet bag's name of a single-robot bag topic for ``robot`` (fleet topics unchanged)."""
    return topic if topic in FLEET_TOPICS else namespace(robot) + topic


def fleet_msgtypes(robots) -> dict[str, str]:
    """Topic -> type of the fleet bag, in the single-robot topic order, robot by robot."""
    types = {t: MSGTYPES[t] for t in FLEET_TOPICS}
    for robot in robots:
        types.update({robot_topic(robot, t): m for t, m in MSGTYPES.items() if t not in FLEET_TOPICS})
    return types


def fleet_latched(robots) -> tuple[str, ...]:
    return (TOPIC_GT_LANDMARKS, *(robot_topic(r, TOPIC_TF_STATIC) for r in robots))


def shared_survey(runs: list[MrclamRun]) -> list[MrclamRun]:
    """The runs with one survey: the label correction the robots that found one agree on (the most
    common), applied to every run's survey (each run's loader looked at its own measurements only)."""
    found = Counter(tuple(sorted(run.survey_relabelled.items())) for run in runs if run.survey_relabelled)
    if not found:
        return runs
    chosen = dict(found.most_common(1)[0][0])
    source = next(run for run in runs if run.survey_relabelled == chosen)
    return [run if run.survey_relabelled == chosen else
            replace(run, landmark_subjects=source.landmark_subjects.copy(), landmark_xy=source.landmark_xy.copy(),
                    survey_relabelled=dict(chosen))
            for run in runs]


def iter_fleet_messages(streams: dict[int, MrclamStreams], typestore=None):
    """Yield (stamp_ns, topic, msgtype, message) of every robot, merged in stamp order; the survey
    once (robot first in ``streams``'s)."""
    first = next(iter(streams))

    def robot_messages(robot: int, s: MrclamStreams):
        for stamp, topic, msgtype, msg in iter_messages(s, typestore):
            if topic in FLEET_TOPICS and robot != first:
                continue
            yield (stamp, TOPIC_PRIORITY[topic], robot), robot_topic(robot, topic), msgtype, msg

    merged = heapq.merge(*(robot_messages(r, s) for r, s in streams.items()), key=lambda m: m[0])
    for (stamp, _, _), topic, msgtype, msg in merged:
        yield stamp, topic, msgtype, msg


def fleet_message_counts(streams: dict[int, MrclamStreams]) -> dict[str, int]:
    counts = {t: 1 for t in FLEET_TOPICS}
    for robot, s in streams.items():
        counts.update({robot_topic(robot, t): n for t, n in s.message_counts().items() if t not in FLEET_TOPICS})
    return counts


def write_fleet_bag(runs: list[MrclamRun], output, storage: str = "mcap", overwrite: bool = False,
                    unknown_ids: bool = False, progress: bool = True, stream=None) -> dict[str, int]:
    """Write the loaded runs of one dataset (one per robot) to the bag directory ``output``;
    returns messages per topic."""
    output = Path(output)
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"storage must be mcap or sqlite3, got {storage!r}")
    if not runs:
        raise ValueError("no robot to convert")
    runs = shared_survey(runs)
    streams = {run.robot: mrclam_streams(run, unknown_ids) for run in runs}
    clear_bag_directory(output, overwrite)
    ts = jazzy_typestore()
    robots = list(streams)
    return write_topics(output, iter_fleet_messages(streams, ts), fleet_message_counts(streams),
                        fleet_msgtypes(robots), fleet_latched(robots), ts, storage,
                        f"mrclam robots {','.join(map(str, robots))} -> {output.name}", progress, stream)


def load_fleet(data_dir, seconds: float | None = None, robots=ROBOTS) -> list[MrclamRun]:
    return [load_mrclam(data_dir, robot, seconds) for robot in robots]


def fleet_report_lines(runs: list[MrclamRun]) -> list[str]:
    """Per robot what its loader left out (the single-robot report), then the robot-to-robot
    reads: dropped (not landmarks), counted."""
    lines = []
    for run in runs:
        lines += [f"robot {run.robot}: {line}" for line in report_lines(run)]
    reads = {run.robot: int(run.drops["other_robot"]) for run in runs}
    lines.append("robot-to-robot barcode reads ignored (dropped, not landmarks): "
                 + ", ".join(f"robot {r} {n}" for r, n in reads.items()) + f" (total {sum(reads.values())})")
    return lines


def run_fleet_cli(args) -> int:
    """``online-em-slam-convert mrclam OUT --all-robots ...``; 0 or 1 (one error line)."""
    if args.robot is not None:
        return fail("--all-robots and --robot exclude each other")
    if args.start:
        return fail("--start is for one robot (--robot K); a fleet's bag starts at the dataset's start")

    def convert():
        runs = load_fleet(args.data_dir, args.seconds)
        counts = write_fleet_bag(runs, args.output, args.storage, args.overwrite, args.unknown_ids,
                                 progress=not args.no_progress)
        return counts, fleet_report_lines(runs)

    return convert_cli(args, convert, width=36)
