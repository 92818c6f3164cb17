"""Issue 25 item 3 offline: a fleet bag run as one node per robot, each node a FleetSlam that
drives only its own robot and folds in the others' segment messages (FleetSlam.share_segments,
outgoing, fold_remote; docs/METHOD.md, "Fleet mode", "Distributed"), against the fleet in one
process.  Messages go to every other node after each input (no delay), except that with
``--lose-every N`` every N-th message of each robot is lost on its way to each other node.

    python docs/scripts/fleet_distributed_check.py bags/d1 --params config/mrclam.yaml --seed 0

Prints one JSON line: each node's map scored as ``run --fleet`` scores its joint map (by id,
shape after the rigid fit), the largest and mean distance between the nodes' landmarks, and
the same for the one-process fleet.  The warm-up replay is off in both (a node's replay would
restart the map without the others' segments, so distributed nodes do not replay).
"""
from __future__ import annotations

import argparse
from collections import Counter
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from online_em_slam.core import FleetSlam  # noqa: E402
from online_em_slam.offline import cli  # noqa: E402
from online_em_slam.offline.evaluation import landmark_metrics_by_id  # noqa: E402
from online_em_slam.offline.fleet_runner import feed_fleet, fleet_initial_poses, read_fleet_inputs  # noqa: E402
from online_em_slam.pipeline.fleet import FleetPipeline  # noqa: E402


def score(landmarks, inputs) -> dict:
    truth = inputs.robots[0].landmarks
    keep = landmarks.confirmed
    m = landmark_metrics_by_id(landmarks.positions[keep], landmarks.ids[keep], truth,
                               inputs.robots[0].landmark_ids, gate=1.0)
    return {"n_matched": m.n_matched, "n_spurious": m.n_spurious, "rmse": round(m.rmse, 4),
            "shape": round(m.shape_error, 4)}


def distributed(config, settings, inputs, initial, lose_every: int) -> list:
    nodes = [FleetSlam(config, [p.pose for p in initial]) for _ in inputs.robots]
    pipelines = [FleetPipeline(node, settings.motion_source, settings.input_delay, settings.time_jump_threshold)
                 for node in nodes]
    for node in nodes:
        node.share_segments()
    for r, kind, stamp, payload, log_time in inputs.events([Counter() for _ in inputs.robots]):
        pipelines[r].push(r, kind, stamp, payload, log_time)
        exchange(nodes, pipelines, lose_every)
    for pipeline in pipelines:
        pipeline.flush()
    exchange(nodes, pipelines, lose_every)
    return nodes


def exchange(nodes, pipelines, lose_every: int) -> None:
    for r, node in enumerate(nodes):
        for message in node.outgoing():
            for q, other in enumerate(nodes):
                if q != r and not (lose_every and message.sequence % lose_every == 0):
                    other.fold_remote(message)
                    pipelines[q].pipelines[q].checkpoint()   # changed outside its inputs: a restore keeps it


def spread(maps: list) -> tuple[float, float]:
    ids = set.intersection(*(set(m) for m in maps))
    d = [np.hypot(*(m[i] - maps[0][i])) for m in maps[1:] for i in ids]
    return (round(float(max(d)), 6), round(float(np.mean(d)), 6)) if d else (0.0, 0.0)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bag")
    p.add_argument("--params", nargs="+", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lose-every", type=int, default=0)
    args = p.parse_args()
    run_args = cli.build_parser().parse_args(["run", args.bag, "--fleet", "--params", *args.params,
                                              "--seed", str(args.seed), "--output", "/dev/null"])
    config, settings, file_values = cli.read_parameters(run_args)
    config = replace(config, noise_learning=replace(config.noise_learning, replay_warmup=False))
    inputs = read_fleet_inputs(args.bag, settings)
    initial = fleet_initial_poses(run_args.initial_pose, inputs, config, settings, file_values)
    fleet = FleetSlam(config, [q.pose for q in initial])
    feed_fleet(fleet, inputs, settings)
    nodes = distributed(config, settings, inputs, initial, args.lose_every)
    maps = [dict(zip(n.landmarks().ids.tolist(), n.landmarks().positions)) for n in nodes]
    joint = dict(zip(fleet.landmarks().ids.tolist(), fleet.landmarks().positions))
    print(json.dumps({"bag": args.bag, "seed": args.seed, "lose_every": args.lose_every,
                      "fleet": score(fleet.landmarks(), inputs),
                      "nodes": [score(n.landmarks(), inputs) for n in nodes],
                      "between_nodes_max_mean_m": spread(maps),
                      "node0_vs_fleet_max_mean_m": spread([maps[0], joint])}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
