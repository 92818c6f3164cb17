"""Issue 25 item 3 over DDS (docs/RESULTS.md, "Fleet"): the MRCLAM fleet bag replayed into one node
process per robot (``local_robot``, node ``slam_robotK``), the nodes sharing the map on
``segments_topic`` (ros/segment_link.py), against the fleet in one process (``run --fleet``).

    python docs/scripts/fleet_distributed_live.py /work/bags/fleet_d1 --rate 5 --offline RUN_DIR

RUN_DIR: ``online-em-slam run BAG --fleet --params config/mrclam.yaml --seed 0 --match-gate 1.0
--output RUN_DIR`` (the warm-up replay does not run in the distributed mode, so compare with a
run with ``noise_learning.replay_warmup: false`` for the map's timing alone).  Prints one JSON
line: per node the messages published to and received by it, its segments sent / folded / lost,
its map scored as ``run --fleet`` scores the joint map, the largest and mean distance between
the nodes' landmarks and from node 1's to the offline run's.  ROS_DOMAIN_ID: this script's
(default 57).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet_replay_check import (KINDS, against_offline, fleet_setup, node_map, offline_map,  # noqa: E402
                                replay_while_spinning, score_map)


def start_nodes(params: Path, robots, initial, seed: int, log_dir: Path, extra=()) -> list:
    poses = ", ".join(f"{v:.9f}" for p in initial for v in (p.x, p.y, p.yaw))
    procs = []
    for robot in robots:
        cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "-r", f"__node:=slam_{robot}",
               "--params-file", str(params), "-p", "use_sim_time:=true", "-p", f"filter.seed:={seed}",
               "-p", f"robots:=[{', '.join(robots)}]", "-p", f"initial_poses:=[{poses}]",
               "-p", f"local_robot:={robot}"]
        for item in extra:
            cmd += ["-p", item]
        log = open(log_dir / f"{robot}.log", "w")
        procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT))
    return procs


def watch(node, robots, seen: dict) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    for r in robots:
        node.create_subscription(PointCloud2, f"/slam_{r}/landmarks",
                                 lambda m, r=r: seen["maps"].__setitem__(r, m), latched)

    def on_diag(msg):
        for status in msg.status:
            name = status.name.split(":")[0]
            if name.startswith("slam_"):
                seen["diag"][name.removeprefix("slam_")] = {kv.key: kv.value for kv in status.values}
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, QoSProfile(depth=50))


def settled(diag: dict, robots) -> bool:
    if any(r not in diag or diag[r].get("queued_inputs") != "0" for r in robots):
        return False
    sent = sum(int(diag[r].get("segments.sent", 0)) for r in robots)
    return all(int(diag[r].get("segments.folded", 0)) + int(diag[r].get("segments.sent", 0)) == sent
               for r in robots)


def replay_and_watch(bag: Path, robots, rate: float, timeout: float, log_dir: Path) -> dict:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    topics = [f"/{r}/{k}" for r in robots for k in KINDS]
    context = Context()
    rclpy.init(context=context)
    seen = {"maps": {}, "diag": {}}
    try:
        node = rclpy.create_node("fleet_distributed_live", context=context)
        watch(node, robots, seen)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        seen["replay"] = replay_while_spinning(bag, topics, rate, timeout, executor, log_dir,
                                               clock_subscribers=len(robots))[0]
        end, last, quiet = time.monotonic() + 600.0, None, time.monotonic()
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            now = json.dumps(seen["diag"], sort_keys=True)
            if now != last:
                last, quiet = now, time.monotonic()
            elif time.monotonic() - quiet > 3.0 and settled(seen["diag"], robots):
                break
        seen["settle_s"] = round(time.monotonic() - (end - 600.0), 1)
        until = time.monotonic() + 3.0
        while time.monotonic() < until:
            executor.spin_once(timeout_sec=0.05)
    finally:
        rclpy.shutdown(context=context)
    return seen


def spread(maps: dict) -> dict:
    """Largest and mean distance of every node's landmarks from the first node's, by id."""
    tables = [{int(i): p for i, p in zip(ids, xy)} for ids, xy in maps.values()]
    common = set.intersection(*(set(t) for t in tables))
    d = [float(np.hypot(*(t[i] - tables[0][i]))) for t in tables[1:] for i in common]
    return {"common_ids": len(common), "max_m": round(max(d), 6) if d else None,
            "mean_m": round(float(np.mean(d)), 6) if d else None}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--params", type=Path, default=ROOT / "config" / "mrclam.yaml")
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--match-gate", type=float, default=1.0)
    parser.add_argument("--offline", type=Path, default=None)
    parser.add_argument("--node-param", nargs="*", default=[], metavar="NAME:=VALUE")
    parser.add_argument("--output", type=Path, default=Path("out/fleet_distributed_live"))
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_DOMAIN_ID", "57")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    args.output.mkdir(parents=True, exist_ok=True)
    robots, initial, inputs, _ = fleet_setup(args.bag, args.params, args.seed)
    from rosbags.rosbag2 import Reader
    with Reader(args.bag) as reader:
        duration = reader.duration * 1e-9
    procs = start_nodes(args.params, robots, initial, args.seed, args.output, args.node_param)
    try:
        seen = replay_and_watch(args.bag, robots, args.rate, duration / args.rate + 1800.0, args.output)
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    published = seen["replay"]["published"]
    nodes, maps = {}, {}
    for r in robots:
        d = seen["diag"].get(r, {})
        entry = {"published": sum(published.get(f"/{r}/{k}", 0) for k in KINDS),
                 "received": int(d.get(f"inputs.{r}", 0)) + sum(int(d.get(f"dropped.{r}.{k}", 0))
                                                                 for k in ("empty_cloud", "malformed_cloud")),
                 **{k: int(d.get(k, 0)) for k in ("segments.sent", "segments.folded", "segments.lost",
                                                  "segments.duplicate", "dropped_total")},
                 "dropped": {k.removeprefix("dropped."): int(v) for k, v in d.items() if k.startswith("dropped.")}}
        if r in seen["maps"]:
            ids, xy, _ = node_map(seen["maps"][r])
            maps[r] = (ids, xy)
            entry["map"] = score_map(ids, xy, inputs, args.match_gate)
        nodes[r] = entry
    result = {"bag": str(args.bag), "rate": args.rate, "replay_wall_s": seen["replay"]["wall_seconds"],
              "target_wall_s": round(duration / args.rate, 1), "settle_s": seen["settle_s"],
              "loadavg": os.getloadavg(), "nodes": nodes, "between_nodes": spread(maps) if len(maps) > 1 else None}
    if args.offline is not None and maps:
        rows, metrics = offline_map(args.offline)
        result["offline_map"] = metrics
        result["node1_vs_offline"] = against_offline(*maps[robots[0]], rows)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
