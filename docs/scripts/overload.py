"""Overload of the live node: the Car Park bag looped, best effort, faster than the node can filter.

    python docs/scripts/overload.py --rate 20 --loops 5 [--output out/overload/rate20.json] [-p NAME:=VALUE ...]

The node runs as its own process (``python -m online_em_slam.ros.node``, rclpy.spin) with
config/car_park.yaml, ``use_sim_time`` and ``input_qos.reliability: best_effort``; the bag is
replayed with ``--loop --clock`` at ``--rate`` for ``--loops`` passes (then SIGINT: the replay
prints what it published).  This process listens to /clock and /diagnostics and reports, as JSON:

* ``lag_max_s``: the estimator's lag behind its inputs, measured from outside: the latest /clock
  (the replay's time) minus the node's ``last_stamp`` at each /diagnostics message, in bag
  seconds (unwrapped at the loop seams), its maximum over the run (the first pass's start-up left out);
* the node's counters: ``dropped.*`` (``out_of_order``, ``overload``, ``*_lost``, ``message_lost``),
  its own lag statistic (``input_lag_max``), ``queued_inputs`` at most;
* ``published`` (by the replay) and ``inputs`` (accounted for by the node).
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

ROOT = Path(__file__).resolve().parents[2]
NODE = "online_em_slam"


def prepare(out: Path):
    from online_em_slam.datasets.kth.convert import convert
    from online_em_slam.offline.runner import choose_initial_pose, read_inputs
    from online_em_slam.parameters.yaml_file import config_from_params, load_params

    bag = out / "car_park_bag"
    if not bag.exists():
        convert("car_park", bag, progress=False)
    params = ROOT / "config" / "car_park.yaml"
    values = load_params(params)
    config, settings = config_from_params(values)
    inputs = read_inputs(bag, settings)
    initial = choose_initial_pose("gps", inputs, config, settings, values)
    return bag, params, initial


def bag_seconds(bag: Path) -> float:
    from rosbags.rosbag2 import Reader
    with Reader(bag) as reader:
        return (reader.end_time - reader.start_time) * 1e-9


def diag_values(status) -> dict:
    out = {}
    for kv in status.values:
        try:
            out[kv.key] = float(kv.value)
        except ValueError:
            out[kv.key] = kv.value
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rate", type=float, default=20.0)
    parser.add_argument("--loops", type=float, default=5.0)
    parser.add_argument("--output", default=None)
    parser.add_argument("--work", default=str(ROOT / "out" / "overload"))
    parser.add_argument("--domain-id", type=int, default=101, help="ROS_DOMAIN_ID of the run (default 101)")
    parser.add_argument("--profile", default=None, help="run the node under cProfile, writing to this file")
    parser.add_argument("-p", dest="params", action="append", default=[], help="extra node parameter NAME:=VALUE")
    args = parser.parse_args()

    os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    bag, params, initial = prepare(work)
    duration = bag_seconds(bag)

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    profile = ["-m", "cProfile", "-o", args.profile] if args.profile else []
    node_cmd = [sys.executable, *profile, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file", str(params),
                "-p", "use_sim_time:=true", "-p", "input_qos.reliability:=best_effort",
                "-p", f"initial_pose.x:={initial.x:.9f}", "-p", f"initial_pose.y:={initial.y:.9f}",
                "-p", f"initial_pose.yaw:={initial.yaw:.12f}", "-p", "publish_particles:=false",
                "-p", "diagnostics_period:=0.25"]
    for extra in args.params:
        node_cmd += ["-p", extra]
    log = open(work / f"node_rate{args.rate:g}.log", "w")
    node_proc = subprocess.Popen(node_cmd, stdout=log, stderr=subprocess.STDOUT)
    context = Context()
    rclpy.init(context=context)
    state = {"clock": None, "diag": {}, "lags": [], "queued_max": 0.0}
    try:
        rec = rclpy.create_node("overload_probe", context=context)

        def on_clock(msg):
            state["clock"] = msg.clock.sec + 1e-9 * msg.clock.nanosec

        def on_diag(msg):
            for status in msg.status:
                if not status.name.startswith(f"{NODE}:"):
                    continue
                values = diag_values(status)
                state["diag"] = values
                state["queued_max"] = max(state["queued_max"], float(values.get("queued_inputs", 0)))
                last, clock = float(values.get("last_stamp", -1.0)), state["clock"]
                if last > 0 and clock is not None:
                    lag = clock - last
                    if lag < -0.5 * duration:        # the replay looped, the node not yet
                        lag += duration
                    state["lags"].append((time.monotonic(), lag))

        rec.create_subscription(Clock, "/clock", on_clock, QoSProfile(depth=1,
                                                                      reliability=ReliabilityPolicy.BEST_EFFORT))
        rec.create_subscription(DiagnosticArray, "/diagnostics", on_diag, QoSProfile(depth=50))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(rec)
        replay_cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", f"{args.rate:g}",
                      "--clock", "--loop", "--topics", "/control", "/odom", "/landmark_observations",
                      "--wait-subscribers", "/control:1", "/odom:1", "/landmark_observations:1", "/clock:2",
                      "--wait-timeout", "60", "--quiet"]
        replay = subprocess.Popen(replay_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        while state["clock"] is None:
            executor.spin_once(timeout_sec=0.05)
            if replay.poll() is not None:
                raise RuntimeError(replay.stderr.read())
        started = time.monotonic()
        play = args.loops * duration / args.rate
        while time.monotonic() - started < play:
            executor.spin_once(timeout_sec=0.02)
        replay.send_signal(signal.SIGINT)
        out, err = replay.communicate(timeout=30)
        stopped = time.monotonic()
        drained = None
        while time.monotonic() - stopped < 30:      # the node works off what it holds
            executor.spin_once(timeout_sec=0.05)
            if state["diag"].get("queued_inputs", 1) == 0 and time.monotonic() - stopped > 2.0:
                drained = time.monotonic() - stopped
                break
        summary = json.loads(out.strip().splitlines()[-1])
        rec.destroy_node()
    finally:
        if node_proc.poll() is None:
            node_proc.send_signal(signal.SIGINT)
            try:
                node_proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                node_proc.kill()
        rclpy.shutdown(context=context)
    diag = state["diag"]
    settle = started + 2.0          # the first pass's start-up (discovery, the warm-up) left out
    lags = [lag for wall, lag in state["lags"] if settle <= wall <= stopped]
    result = {
        "rate": args.rate, "loops": args.loops, "bag_seconds": duration, "play_wall_s": play,
        "published": summary.get("published"),
        "published_total": sum(summary.get("published", {}).values()),
        "inputs": diag.get("inputs"), "observation_updates": diag.get("observation_updates"),
        "lag_max_s": max(lags, default=None), "lag_mean_s": sum(lags) / len(lags) if lags else None,
        "queued_max": state["queued_max"], "drained_after_s": drained,
        "node": {k: v for k, v in diag.items() if k.startswith(("dropped.", "input_lag", "load", "resets"))},
        "params": args.params,
    }
    text = json.dumps(result, indent=2)
    print(text)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
