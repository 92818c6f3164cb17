"""Soak (docs/RESULTS.md, "Reliability"): the Car Park bag replayed over DDS in a loop into the
node (separate processes, /clock) until ``--messages`` inputs were published; the node's
resident memory, inputs and drops are sampled every ``--every`` seconds.

    python docs/scripts/soak.py --messages 300000 --rate 5 --reliability best_effort

Each pass of the loop is a confirmed backward time jump: the node restarts the pose and
keeps the map (issue 12).  Prints one JSON line per sample and a summary line.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from input_path_figures import INPUTS, process_cpu_seconds, start_node  # noqa: E402

CAR_PARK_MESSAGES_PER_S = 10588 / 125.05          # the input topics of the bag, at rate 1


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--messages", type=int, default=300_000)
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--reliability", default="best_effort", choices=("best_effort", "reliable"))
    parser.add_argument("--every", type=float, default=10.0)
    parser.add_argument("--output", default="out/soak")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default 200 + pid %% 30)")
    args = parser.parse_args(argv)
    # A domain no test or demo uses (they take 1-179): a replay of theirs on the same domain
    # would reach this node (a first soak met one: 44 resets, a duplicated map).
    os.environ["ROS_DOMAIN_ID"] = str(args.domain_id if args.domain_id is not None else 200 + os.getpid() % 30)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile

    from car_park_setup import car_park

    out = Path(args.output)
    bag, params, values, config, settings, _, initial = car_park(out, 0)
    log = open(out / "node.log", "w")
    node = start_node(params, initial, 0, args.reliability, log)
    context = Context()
    rclpy.init(context=context)
    diag: dict = {}
    try:
        rec = rclpy.create_node("soak_recorder", context=context)

        def on_diag(msg):
            for status in msg.status:
                if status.name.startswith("online_em_slam:"):
                    diag.update({kv.key: kv.value for kv in status.values})
        rec.create_subscription(DiagnosticArray, "/diagnostics", on_diag, QoSProfile(depth=50))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(rec)
        cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", str(args.rate), "--clock",
               "--loop", "--topics", *INPUTS, "--wait-subscribers", *(f"{t}:1" for t in INPUTS), "/clock:1",
               "--wait-timeout", "60", "--start-delay", "2", "--quiet"]
        replay = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        duration = args.messages / (CAR_PARK_MESSAGES_PER_S * args.rate)
        started = None
        next_sample = time.monotonic()
        samples = []
        while True:
            executor.spin_once(timeout_sec=0.05)
            if started is None and diag.get("inputs", "0") != "0":
                started = time.monotonic()
            now = time.monotonic()
            if now >= next_sample:
                next_sample = now + args.every
                sample = {"t": round(now - (started or now), 1), "rss_mb": round(rss_mb(node.pid), 1),
                          "inputs": int(diag.get("inputs", 0)), "resets": diag.get("resets"),
                          "landmarks": diag.get("landmarks"), "load": os.getloadavg()[0],
                          "drops": {k[8:]: int(v) for k, v in diag.items() if k.startswith("dropped.")}}
                samples.append(sample)
                print(json.dumps(sample), flush=True)
            if started is not None and now - started >= duration:
                break
        replay.send_signal(signal.SIGINT)
        out_text, _ = replay.communicate(timeout=30)
        summary = json.loads(out_text.strip().splitlines()[-1])
        settle = time.monotonic() + 5.0
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)
    finally:
        rclpy.shutdown(context=context)
        node_cpu = process_cpu_seconds(node.pid)
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
    drops = {k[8:]: int(v) for k, v in diag.items() if k.startswith("dropped.")}
    received = int(diag.get("inputs", 0)) + sum(drops.get(k, 0) for k in ("empty_cloud", "malformed_cloud"))
    rss = [s["rss_mb"] for s in samples if s["t"] > 0]
    print(json.dumps({"summary": True, "rate": args.rate, "reliability": args.reliability,
                      "published": summary["total"], "received": received, "lost": summary["total"] - received,
                      "drops": drops, "resets": diag.get("resets"), "landmarks": diag.get("landmarks"),
                      "rss_mb_first": rss[0] if rss else None, "rss_mb_max": max(rss) if rss else None,
                      "rss_mb_last": rss[-1] if rss else None, "node_cpu_s": node_cpu,
                      "wall_s": round(time.monotonic() - started, 1) if started else None,
                      "loadavg": os.getloadavg()}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
