"""Figures of the input path (docs/RESULTS.md, "Input path"): the Car Park bag replayed over
DDS into the node (separate processes) at several rates.

    python docs/scripts/input_path_figures.py --rates 1 --reliability reliable   # agreement, pose gaps
    python docs/scripts/input_path_figures.py --rates 10 20 30 40 60              # sustained rate sweep
    python docs/scripts/input_path_figures.py --rates 20 --loops 5 [--set filter.num_particles:=1000]
                                                                    # overload: five passes in a loop

Per rate: messages published and received, drops by reason, the node's peak load, the
largest gap between consecutive ~/pose messages (wall arrival time in this process and
stamps), and, with --compare, the node's ~/path and ~/landmarks against the offline runner
(``online-em-slam run``'s feed, in memory) on the same bag with the same settings; the
node's peak queue wait (``queue_wait_peak_ms``) and how far its ~/pose stamps ran behind the
replay's /clock (``lag_*_bag_s``); ``--series``: every /diagnostics message's queue wait,
load and drops.  Prints one JSON line per rate.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

INPUTS = ("/control", "/odom", "/landmark_observations")
BAG_SECONDS = 125.05        # the Car Park bag's duration


def start_node(params, initial, seed, reliability, log, extra=()):
    cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file", str(params),
           "-p", "use_sim_time:=true", "-p", f"filter.seed:={seed}", "-p", f"initial_pose.x:={initial.x:.9f}",
           "-p", f"initial_pose.y:={initial.y:.9f}", "-p", f"initial_pose.yaw:={initial.yaw:.12f}",
           "-p", "publish_particles:=false", "-p", "path_publish_max_poses:=20000",
           "-p", f"input_qos.reliability:={reliability}", *(a for kv in extra for a in ("-p", kv))]
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)


def process_cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a running process (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def watch_map_and_diagnostics(node, seen: dict) -> None:
    """The node's latched map into seen["landmarks"], its /diagnostics values into seen["diag"]."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(PointCloud2, "/online_em_slam/landmarks", lambda m: seen.__setitem__("landmarks", m),
                             latched)

    def on_diag(msg):
        for status in msg.status:
            if status.name.startswith("online_em_slam:"):
                seen["diag"] = {kv.key: kv.value for kv in status.values}
                seen.setdefault("diag_series", []).append(seen["diag"])
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, QoSProfile(depth=50))


def record(bag, rate, timeout=400.0, loops=0):
    """Replay ``bag`` at ``rate`` (``loops`` > 0: in a loop, stopped after that many passes) and
    record the node's outputs; returns what was seen."""
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Path as PathMsg
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    context = Context()
    rclpy.init(context=context)
    from rosgraph_msgs.msg import Clock
    seen = {"poses": [], "path": None, "landmarks": None, "diag": {}, "clock": None, "lags": []}
    try:
        node = rclpy.create_node("input_path_recorder", context=context)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        def on_pose(m):
            stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            seen["poses"].append((time.monotonic(), stamp))
            if seen["clock"] is not None and seen["clock"] >= stamp:   # behind the replay's clock (not across a seam)
                seen["lags"].append(seen["clock"] - stamp)
        node.create_subscription(PoseWithCovarianceStamped, "/online_em_slam/pose", on_pose,
                                 QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(Clock, "/clock", lambda m: seen.__setitem__(
            "clock", m.clock.sec + 1e-9 * m.clock.nanosec), QoSProfile(depth=10))
        node.create_subscription(PathMsg, "/online_em_slam/path", lambda m: seen.__setitem__("path", m), latched)
        watch_map_and_diagnostics(node, seen)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", str(rate), "--clock",
               "--topics", *INPUTS, "--wait-subscribers", *(f"{t}:1" for t in INPUTS), "/clock:1",
               "--wait-timeout", "60", "--start-delay", "2", "--quiet"] + (["--loop"] if loops else [])
        replay = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + timeout
        stop_at = None
        while replay.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
            if loops and stop_at is None and seen["clock"] is not None:
                stop_at = time.monotonic() + loops * BAG_SECONDS / rate
            if stop_at is not None and time.monotonic() > stop_at:
                replay.send_signal(signal.SIGINT)     # the replay prints its summary and exits
                stop_at = math.inf
        out, err = replay.communicate(timeout=30)
        summary = json.loads(out.strip().splitlines()[-1])
        published, seen["replay_wall_s"] = summary["published"], summary["wall_seconds"]
        settle, last = time.monotonic() + 30.0, None
        while time.monotonic() < settle:          # until the diagnostics stop changing
            executor.spin_once(timeout_sec=0.05)
            now = (seen["diag"].get("inputs"), seen["diag"].get("queued_inputs"), len(seen["poses"]))
            if now != last:
                last, quiet_since = now, time.monotonic()
            elif time.monotonic() - quiet_since > 3.0 and seen["diag"].get("queued_inputs") == "0":
                break
    finally:
        rclpy.shutdown(context=context)
    seen["published"] = published
    return seen


def summarise(seen, rate):
    diag = seen["diag"]
    drops = {k.split(".", 1)[1]: int(v) for k, v in diag.items() if k.startswith("dropped.")}
    # An empty cloud is not an input but a decision (decided.empty_cloud); a malformed one a drop.
    received = (int(diag.get("inputs", 0)) + int(diag.get("decided.empty_cloud", 0))
                + drops.get("malformed_cloud", 0))
    total = sum(seen["published"].values())
    poses = np.array(seen["poses"]).reshape(-1, 2)
    order = np.argsort(poses[:, 1], kind="stable")
    return {"rate": rate, "messages_per_s": round(total / (BAG_SECONDS / rate), 1), "published": total,
            "achieved_messages_per_s": round(total / seen["replay_wall_s"], 1),
            "received": received, "lost": total - received, "drops": drops,
            "load_max": float(diag.get("load_max", "nan")),
            "queue_wait_peak_ms": float(diag.get("queue_wait_peak_ms", "nan")), "pose_messages": len(poses),
            "max_pose_gap_wall_ms": round(1e3 * float(np.diff(poses[:, 0]).max()), 1) if len(poses) > 1 else None,
            "max_pose_gap_stamp_ms": round(1e3 * float(np.diff(poses[order, 1]).max()), 1)
            if len(poses) > 1 else None,
            "largest_wall_gaps": _largest_gaps(poses),
            "lag_max_bag_s": round(max(seen["lags"]), 3) if seen["lags"] else None,
            "lag_p99_bag_s": round(float(np.percentile(seen["lags"], 99)), 3) if seen["lags"] else None}


def _largest_gaps(poses, n=3):
    """The n largest wall gaps between ~/pose arrivals: (gap ms, bag time of the pose after it).
    The last pose of the bag comes input_delay after the end (the merge waits that long for
    the streams that stopped), so its gap is the end of the bag, not a gap in the flow."""
    if len(poses) < 2:
        return []
    gaps = np.diff(poses[:, 0])
    top = np.argsort(gaps)[::-1][:n]
    return [(round(1e3 * float(gaps[i]), 1), round(float(poses[i + 1, 1] - poses[0, 1]), 3)) for i in top]


def compare(seen, inputs, config, settings, initial):
    """Node outputs against the offline runner (runner.feed, the bag streamed) on the same bag."""
    from online_em_slam.offline import runner as cli
    from online_em_slam.messages.cloud import decode_message
    from online_em_slam.offline.evaluation import sensor_points, trajectory_metrics

    runner = cli.feed(cli.make_estimator("online_em", config, initial.pose), inputs)
    offset = (config.sensor.offset_x, config.sensor.offset_y)

    def rmse(traj):
        return trajectory_metrics(traj[:, 0], sensor_points(traj[:, 1:4], offset), inputs.gps_times,
                                  inputs.gps_xy).rmse
    traj = np.array([(p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec, p.pose.position.x, p.pose.position.y,
                      2 * np.arctan2(p.pose.orientation.z, p.pose.orientation.w)) for p in seen["path"].poses])
    cols = decode_message(seen["landmarks"])               # float32 fields
    node_ids, node_xy = np.asarray(cols["id"], int), np.stack([cols["x"], cols["y"]], axis=1)
    lm = runner.landmarks
    same = sorted(node_ids) == sorted(int(i) for i in lm.ids)
    node_xy = node_xy[np.argsort(node_ids)]
    runner_xy = np.asarray(lm.positions)[np.argsort(lm.ids)]
    return {"trajectory_rmse_node_m": rmse(traj), "trajectory_rmse_runner_m": rmse(runner.trajectory),
            "trajectory_points_node": len(traj), "trajectory_points_runner": len(runner.trajectory),
            "trajectory_max_abs_diff_m": float(np.abs(traj[:, 1:3] - runner.trajectory[:, 1:3]).max())
            if len(traj) == len(runner.trajectory) else None,
            "landmarks_node": len(node_ids), "landmarks_runner": len(lm.ids),
            "landmark_max_abs_diff_m": float(np.abs(node_xy - runner_xy).max()) if same else None,
            "landmark_max_abs_diff_vs_float32_m": float(np.abs(node_xy - runner_xy.astype(np.float32)).max())
            if same else None}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[1.0])
    parser.add_argument("--reliability", default="best_effort", choices=("best_effort", "reliable"))
    parser.add_argument("--compare", action="store_true", help="compare with the offline runner")
    parser.add_argument("--loops", type=int, default=0, help="play the bag in a loop, this many passes")
    parser.add_argument("--series", action="store_true", help="print the /diagnostics series too")
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME:=VALUE", help="node parameters")
    parser.add_argument("--output", default="out/input_path")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.environ["ROS_DOMAIN_ID"] = str(1 + os.getpid() % 100)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    from car_park_setup import car_park

    out = Path(args.output)
    bag, params, values, config, settings, inputs, initial = car_park(out, args.seed)
    for rate in args.rates:
        with open(out / f"node_rate{rate:g}.log", "w") as log:
            node = start_node(params, initial, args.seed, args.reliability, log, args.set)
            try:
                seen = record(bag, rate, loops=args.loops)
                seen["node_cpu_s"] = process_cpu_seconds(node.pid)
            finally:
                node.send_signal(signal.SIGINT)
                try:
                    node.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    node.kill()
        result = {"reliability": args.reliability, **summarise(seen, rate), "node_cpu_s": seen["node_cpu_s"],
                  "loadavg": os.getloadavg()}
        if args.compare:
            result.update(compare(seen, inputs, config, settings, initial))
        if args.series:
            result["series"] = [{k: d.get(k) for k in ("queue_wait_max_ms", "load", "dropped.overload",
                                                        "dropped.stamp_outlier", "dropped.odometry_lost", "resets")}
                                for d in seen.get("diag_series", [])]
        print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
