"""Issue 25's check "five robots replayed at 5x real time into the fleet node without loss"
(docs/RESULTS.md, "Fleet"): the MRCLAM fleet bag replayed over DDS (online-em-slam-replay, a
separate process, with /clock) into the node in fleet mode (another process, use_sim_time,
every robot started at its first ground-truth pose as ``run --fleet`` starts it).

    online-em-slam-convert mrclam /tmp/fleetlive/d1 --all-robots --seconds 600 \\
        --data-dir ../shared/datasets/mrclam/MRCLAM_Dataset1.tar.xz
    online-em-slam run /tmp/fleetlive/d1 --fleet --params config/mrclam.yaml --seed 0 \\
        --match-gate 1.0 --output /tmp/fleetlive/offline
    python docs/scripts/fleet_replay_check.py /tmp/fleetlive/d1 --rates 5 1 --offline /tmp/fleetlive/offline

Per rate: the messages the replay published per robot (its /robotK/control, /robotK/odom and
/robotK/landmark_observations; the ground truth and /robotK/tf are not replayed: the node does
not read them) against what the node received per robot (``inputs.robotK`` in /diagnostics,
plus clouds dropped as empty or malformed), the node's drops per robot and reason
(``dropped.robotK.*``: ``*_lost``, ``out_of_order``, ``overload``, ...), the replay's wall time
against the bag's duration / rate, and the node's final joint map (its latched ~/landmarks)
scored as ``run --fleet`` scores its map (by id, within --match-gate, shape after the rigid fit)
and against the offline run's landmarks.csv / metrics.json (--offline).  Prints one JSON line per
rate.  The node runs with config/mrclam.yaml's settings (input_qos.reliability: reliable), its
ROS_DOMAIN_ID is this script's (set one: ``ROS_DOMAIN_ID=57 python ...``; default 57).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
KINDS = ("control", "odom", "landmark_observations")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from input_path_figures import process_cpu_seconds, watch_map_and_diagnostics  # noqa: E402


def fleet_setup(bag: Path, params: Path, seed: int):
    """(robot names, initial poses, the fleet's bag inputs, SlamConfig): what ``run --fleet`` reads."""
    from online_em_slam.offline.fleet_runner import fleet_initial_poses, read_fleet_inputs
    from online_em_slam.parameters.yaml_file import config_from_params, load_params

    values = load_params(params)
    config, settings = config_from_params(values, {"filter.seed": seed})
    inputs = read_fleet_inputs(bag, settings)
    initial = fleet_initial_poses("ground_truth", inputs, config, settings, values)
    return [ns.strip("/") for ns in inputs.names], initial, inputs, config


def start_node(params: Path, robots, initial, seed: int, log, extra=()):
    poses = ", ".join(f"{v:.9f}" for p in initial for v in (p.x, p.y, p.yaw))
    cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file", str(params),
           "-p", "use_sim_time:=true", "-p", f"filter.seed:={seed}",
           "-p", f"robots:=[{', '.join(robots)}]", "-p", f"initial_poses:=[{poses}]"]
    for item in extra:
        cmd += ["-p", item]
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)


def replay_while_spinning(bag: Path, topics, rate: float, timeout: float, executor, log_dir: Path,
                          clock_subscribers: int):
    """Replay ``topics`` of ``bag`` at ``rate`` with /clock (online-em-slam-replay, once ``topics``
    and /clock have their subscribers) while ``executor`` spins; (the replay's summary, its exit
    status, its last stderr lines).  Stopped by SIGINT after ``timeout`` s."""
    cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", str(rate), "--clock",
           "--topics", *topics, "--wait-subscribers", *(f"{t}:1" for t in topics), f"/clock:{clock_subscribers}",
           "--wait-timeout", "120", "--start-delay", "2", "--ack-timeout", "900"]
    replay = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout
    try:
        while replay.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        if replay.poll() is None:
            replay.send_signal(signal.SIGINT)
        out, err = replay.communicate(timeout=60)
    (log_dir / f"replay_rate{rate:g}.err").write_text(err)
    lines = out.strip().splitlines()
    if not lines:
        raise RuntimeError(f"the replay ended with status {replay.returncode} and no summary: "
                           f"{' | '.join(err.strip().splitlines()[-5:])}")
    return json.loads(lines[-1]), replay.returncode, err.strip().splitlines()[-5:]


def replay_and_watch(bag: Path, robots, rate: float, timeout: float, settle_timeout: float, node_pid: int,
                     log_dir: Path, wait_replay: bool = False):
    """Replay the robots' inputs at ``rate`` while watching /diagnostics and ~/landmarks; what was seen.
    ``wait_replay``: settled only once every robot reports its warm-up replay done (the node feeds
    it between its inputs, so it may still be catching up when the inputs end)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    topics = [f"/{r}/{k}" for r in robots for k in KINDS]
    context = Context()
    rclpy.init(context=context)
    seen = {"landmarks": None, "diag": {}}
    try:
        node = rclpy.create_node("fleet_replay_check", context=context)
        watch_map_and_diagnostics(node, seen)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        seen["replay"], seen["replay_exit"], seen["replay_stderr"] = replay_while_spinning(
            bag, topics, rate, timeout, executor, log_dir, clock_subscribers=1)
        seen["node_cpu_s_at_replay_end"] = process_cpu_seconds(node_pid)
        settle, last, quiet_since = time.monotonic() + settle_timeout, None, time.monotonic()
        while time.monotonic() < settle:          # until the node has used everything queued
            executor.spin_once(timeout_sec=0.05)
            now = (seen["diag"].get("inputs"), seen["diag"].get("queued_inputs"),
                   seen["diag"].get("observation_updates"))
            if now != last:
                last, quiet_since = now, time.monotonic()
            elif (time.monotonic() - quiet_since > 5.0 and seen["diag"].get("queued_inputs") == "0"
                  and (not wait_replay or all(seen["diag"].get(f"{r}.noise_learned.warmup_replayed") == "True"
                                              for r in robots))):
                break
        seen["settle_s"] = round(time.monotonic() - (settle - settle_timeout), 1)
        spin_until = time.monotonic() + 5.0       # the map timer's last publication
        while time.monotonic() < spin_until:
            executor.spin_once(timeout_sec=0.05)
    finally:
        rclpy.shutdown(context=context)
    return seen


def per_robot(seen, robots) -> dict:
    """Published / received / dropped (by reason) per robot."""
    diag, published = seen["diag"], seen["replay"]["published"]
    out = {}
    for r in robots:
        drops = {k.split(".", 2)[2]: int(v) for k, v in diag.items() if k.startswith(f"dropped.{r}.")}
        sent = {k: published.get(f"/{r}/{k}", 0) for k in KINDS}
        received = int(diag.get(f"inputs.{r}", 0)) + sum(drops.get(k, 0) for k in ("empty_cloud", "malformed_cloud"))
        out[r] = {"published": sum(sent.values()), "published_by_topic": sent, "received": received,
                  "missing": sum(sent.values()) - received, "dropped": drops}
    return out


def node_map(cloud):
    """(ids, xy, n_obs) of the node's ~/landmarks cloud."""
    from online_em_slam.messages.cloud import decode_message

    cols = decode_message(cloud)
    return (np.asarray(cols["id"], int), np.stack([cols["x"], cols["y"]], axis=1).astype(float),
            np.asarray(cols.get("n_obs", np.zeros(len(cols["id"]))), float))


def score_map(ids, xy, inputs, gate: float) -> dict:
    """The joint map scored as ``run --fleet`` scores it (known ids: paired by id)."""
    from online_em_slam.offline.report import scored_landmarks

    lm = scored_landmarks(xy, ids, inputs.robots[0], gate, by_id=True).to_dict()
    return {k: lm.get(k) for k in ("n_matched", "n_true", "n_spurious", "rmse", "shape_error", "frame_error")}


def offline_map(run_dir: Path):
    """(ids, xy, landmark metrics) of ``online-em-slam run --fleet``'s output (confirmed landmarks)."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    with open(run_dir / "landmarks.csv") as f:
        rows = list(csv.DictReader(f))
    lm = metrics.get("landmarks", {})
    return rows, {k: lm.get(k) for k in ("n_matched", "n_true", "n_spurious", "rmse", "shape_error", "frame_error")}


def against_offline(ids, xy, rows) -> dict:
    """The node's landmarks against the offline run's, by id."""
    table = {int(float(r["id"])): (float(r["x"]), float(r["y"])) for r in rows}
    common = [i for i in ids if int(i) in table]
    diffs = [float(np.hypot(*(xy[list(ids).index(i)] - np.asarray(table[int(i)])))) for i in common]
    return {"common_ids": len(common), "only_node": sorted(set(map(int, ids)) - set(table)),
            "max_diff_m": round(max(diffs), 4) if diffs else None,
            "mean_diff_m": round(float(np.mean(diffs)), 4) if diffs else None}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag", type=Path, help="fleet bag (online-em-slam-convert mrclam DIR --all-robots)")
    parser.add_argument("--params", type=Path, default=ROOT / "config" / "mrclam.yaml")
    parser.add_argument("--rates", type=float, nargs="+", default=[5.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--match-gate", type=float, default=1.0)
    parser.add_argument("--offline", type=Path, default=None,
                        help="output directory of `online-em-slam run BAG --fleet` on the same bag and seed")
    parser.add_argument("--node-param", nargs="*", default=[], metavar="NAME:=VALUE",
                        help="more node parameters (e.g. publish_particles:=false)")
    parser.add_argument("--timeout", type=float, default=2400.0,
                        help="seconds past the bag's duration / rate before the replay is stopped (a node "
                             "slower than the rate holds the reliable replay back)")
    parser.add_argument("--output", type=Path, default=Path("out/fleet_replay_check"), help="node logs")
    parser.add_argument("--wait-replay", action="store_true",
                        help="after the bag, wait (up to 600 s) until the node's warm-up replay has taken over")
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_DOMAIN_ID", "57")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    args.output.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    robots, initial, inputs, config = fleet_setup(args.bag, args.params, args.seed)
    from rosbags.rosbag2 import Reader
    with Reader(args.bag) as reader:
        duration = reader.duration * 1e-9
    print(f"# read {args.bag} ({', '.join(robots)}) in {time.monotonic() - started:.1f} s; bag span "
          f"{duration:.1f} s", file=sys.stderr, flush=True)
    offline = offline_map(args.offline) if args.offline else None
    for rate in args.rates:
        with open(args.output / f"node_rate{rate:g}.log", "w") as log:
            node = start_node(args.params, robots, initial, args.seed, log, args.node_param)
            try:
                seen = replay_and_watch(args.bag, robots, rate, timeout=duration / rate + args.timeout,
                                        settle_timeout=600.0, node_pid=node.pid, log_dir=args.output,
                                        wait_replay=args.wait_replay)
                node_cpu = process_cpu_seconds(node.pid)
            finally:
                node.send_signal(signal.SIGINT)
                try:
                    node.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    node.kill()
                    node.wait()
        diag, replay = seen["diag"], seen["replay"]
        robots_out = per_robot(seen, robots)
        result = {"rate": rate, "replay_wall_s": replay["wall_seconds"], "bag_span_s": round(duration, 1),
                  "target_wall_s": round(duration / rate, 1), "replay_exit": replay_exit_text(seen),
                  "acknowledged": replay["acknowledged"], "skipped_topics": replay["skipped_topics"],
                  "published": sum(r["published"] for r in robots_out.values()),
                  "received": sum(r["received"] for r in robots_out.values()),
                  "node_inputs": int(diag.get("inputs", 0)), "dropped_total": int(diag.get("dropped_total", 0)),
                  "load_max": float(diag.get("load_max", "nan")), "settle_s": seen["settle_s"],
                  "node_cpu_s": node_cpu, "node_cpu_s_at_replay_end": seen["node_cpu_s_at_replay_end"],
                  "loadavg": os.getloadavg(), "robots": robots_out}
        if seen["landmarks"] is not None:
            ids, xy, n_obs = node_map(seen["landmarks"])
            result["node_map"] = {"landmarks": len(ids), **score_map(ids, xy, inputs, args.match_gate)}
            if offline is not None:
                result["offline_map"] = offline[1]
                result["node_vs_offline"] = against_offline(ids, xy, offline[0])
        else:
            result["node_map"] = None
        print(json.dumps(result), flush=True)
    return 0


def replay_exit_text(seen) -> str:
    code = seen["replay_exit"]
    return "ok" if code == 0 else f"{code}: {' | '.join(seen['replay_stderr'])}"


if __name__ == "__main__":
    sys.exit(main())
