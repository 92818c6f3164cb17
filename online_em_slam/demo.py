"""End-to-end demo on the bundled Car Park data: bag -> DDS -> node -> evaluation.

    python -m online_em_slam.demo [--output out/demo] [--rate 5] [--seed 0]

1. converts the bundled KTH Car Park data to a bag (``OUTPUT/car_park_bag``);
2. starts the SLAM node as a separate process (``python -m online_em_slam.ros.node``
   with ``config/car_park.yaml``, ``use_sim_time``, the initial pose from GPS);
3. records the node's ``~/pose``, ``~/path``, ``~/landmarks`` and ``/diagnostics``
   in this process (rclpy);
4. replays the bag as a third process (``python -m online_em_slam.replay`` at
   ``--rate``, with ``/clock``, after the node's subscriptions are matched);
5. checks that every published input reached the node and none was dropped,
   evaluates the recorded outputs against the ground truth in the bag and writes
   ``OUTPUT/{trajectory.csv, landmarks.csv, metrics.json, map.png}``;
6. runs the offline runner (no DDS) on the same bag with the same settings
   (``OUTPUT/offline/``) and prints both results side by side.

All processes share a DDS domain of their own (``ROS_DOMAIN_ID``, default derived
from the process id) with discovery kept on this host
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).  The exit status is 0 when the
node received and used every input, 1 otherwise.
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

NODE_NAME = "online_em_slam"
INPUT_TOPICS = ("/control", "/odom", "/landmark_observations")
# Node drop reasons counted before an input enters its buffer (not in the "inputs" counter).
PRE_BUFFER_DROPS = ("empty_cloud", "malformed_cloud", "non_finite_odometry", "non_finite_control")
# Drops that would mean an input was lost or unused (must be zero in the demo).
INPUT_LOSS_DROPS = ("malformed_cloud", "non_finite_odometry", "non_finite_control", "non_finite_stamp",
                    "out_of_order", "zero_time_step", "no_motion_input", "paused", "internal_error")


def find_params(name: str = "car_park.yaml") -> Path:
    """config/<name> of the source tree, else of the installed package share."""
    here = Path(__file__).resolve().parent.parent / "config" / name
    if here.exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory("online_em_slam")) / "config" / name
    except Exception as error:  # noqa: BLE001
        raise FileNotFoundError(f"config/{name} not found ({error})") from None


def _diag_values(status) -> dict:
    out = {}
    for kv in status.values:
        try:
            out[kv.key] = float(kv.value)
        except ValueError:
            out[kv.key] = kv.value
    return out


def _print_table(rows: list[tuple[str, str, str]]) -> None:
    width = max(len(r[0]) for r in rows)
    print(f"  {'':{width}s}  {'DDS (node)':>14s}  {'offline':>14s}")
    for name, a, b in rows:
        print(f"  {name:{width}s}  {a:>14s}  {b:>14s}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m online_em_slam.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--output", default="out/demo", help="output directory (default out/demo)")
    parser.add_argument("--params", default=None, help="node params file (default config/car_park.yaml)")
    parser.add_argument("--rate", type=float, default=5.0, help="replay rate (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="filter seed of the node and the offline run")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default 1 + pid % 100)")
    parser.add_argument("--timeout", type=float, default=180.0, help="overall time limit of the DDS part (s)")
    args = parser.parse_args(argv)

    # DDS environment before rclpy is imported; children inherit it.
    domain = args.domain_id if args.domain_id is not None else 1 + os.getpid() % 100
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")

    from . import cli
    from .evaluation import landmark_metrics, sensor_points, trajectory_metrics
    from .kth.convert import convert
    from .paramfile import config_from_params, load_params

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    params = Path(args.params) if args.params else find_params()
    bag = out / "car_park_bag"

    print(f"[1/6] converting the bundled Car Park data to {bag}", flush=True)
    convert("car_park", bag, progress=False, overwrite=True)

    file_values = load_params(params)
    config, settings = config_from_params(file_values, {"filter.seed": args.seed})
    inputs = cli.read_inputs(bag, settings)
    initial = cli.choose_initial_pose("gps", inputs, config, settings, file_values)
    print(f"      initial pose from GPS: x={initial.x:.3f} y={initial.y:.3f} yaw={initial.yaw:.4f} "
          f"({initial.source})", flush=True)

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Path as PathMsg
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from .cloud import decode_message
    from .core.types import LandmarkMap

    env = dict(os.environ)
    node_log = open(out / "node.log", "w")
    node_cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file", str(params),
                "-p", "use_sim_time:=true", "-p", f"filter.seed:={args.seed}",
                "-p", f"initial_pose.x:={initial.x:.9f}", "-p", f"initial_pose.y:={initial.y:.9f}",
                "-p", f"initial_pose.yaw:={initial.yaw:.12f}", "-p", "publish_particles:=false",
                # The trajectory error is computed from ~/path: publish every kept pose, not a decimation.
                "-p", "path_publish_max_poses:=20000"]
    print(f"[2/6] starting the node (ROS_DOMAIN_ID={domain}): {' '.join(node_cmd[1:])}", flush=True)
    node_proc = subprocess.Popen(node_cmd, stdout=node_log, stderr=subprocess.STDOUT, env=env)

    context = Context()
    rclpy.init(context=context)
    replay_proc = None
    poses, state = [], {"path": None, "landmarks": None, "diag": None}
    ok = True
    try:
        rec = rclpy.create_node("demo_recorder", context=context)
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pose_qos = QoSProfile(depth=10000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        rec.create_subscription(PoseWithCovarianceStamped, f"/{NODE_NAME}/pose", poses.append, pose_qos)
        rec.create_subscription(PathMsg, f"/{NODE_NAME}/path", lambda m: state.__setitem__("path", m), latched)
        rec.create_subscription(PointCloud2, f"/{NODE_NAME}/landmarks",
                                lambda m: state.__setitem__("landmarks", m), latched)

        def on_diag(msg):
            for status in msg.status:
                if status.name.startswith(f"{NODE_NAME}:"):
                    state["diag"] = _diag_values(status)
        rec.create_subscription(DiagnosticArray, "/diagnostics", on_diag, QoSProfile(depth=50))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(rec)

        replay_cmd = [sys.executable, "-m", "online_em_slam.replay", str(bag), "--rate", str(args.rate), "--clock",
                      "--wait-subscribers", "/control:1", "/odom:1", "/landmark_observations:1", "/clock:1",
                      "--wait-timeout", "60", "--quiet"]
        print(f"[3/6] replaying at rate {args.rate:g} (~{125 / max(args.rate, 1e-9):.0f} s): "
              f"{' '.join(replay_cmd[1:])}", flush=True)
        started = time.monotonic()
        replay_proc = subprocess.Popen(replay_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                       env=env)
        deadline = started + args.timeout
        while replay_proc.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if node_proc.poll() is not None:
                raise RuntimeError(f"the node exited early (code {node_proc.returncode}); see {out / 'node.log'}")
        if replay_proc.poll() is None:
            raise RuntimeError("replay did not finish in time")
        replay_out, replay_err = replay_proc.communicate()
        replay_wall = time.monotonic() - started
        if replay_proc.returncode != 0:
            raise RuntimeError(f"replay failed (code {replay_proc.returncode}): {replay_err.strip()}")
        summary = json.loads(replay_out.strip().splitlines()[-1])
        published = {t: int(summary["published"].get(t, 0)) for t in INPUT_TOPICS}
        total_published = sum(published.values())

        # Wait until the node accounted for every input, then for the final map/path publication.
        print("[4/6] waiting for the node to process the last inputs", flush=True)

        def received(diag):
            return int(diag.get("inputs", 0)) + sum(int(diag.get(f"dropped.{r}", 0)) for r in PRE_BUFFER_DROPS)

        # Done when every input is accounted for, or when nothing changed for a while (inputs lost).
        settle = 2.5 * max(settings.map_publish_period, settings.diagnostics_period)
        settle_until, last_seen, last_change = None, None, time.monotonic()
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            diag = state["diag"]
            if not diag:
                continue
            seen = (received(diag), int(diag.get("observation_updates", 0)))
            if seen != last_seen:
                last_seen, last_change = seen, time.monotonic()
            idle = int(diag.get("queued_inputs", 1)) == 0
            if idle and (received(diag) >= total_published or time.monotonic() - last_change > 3 * settle):
                if settle_until is None:
                    settle_until = time.monotonic() + settle
                elif time.monotonic() > settle_until:
                    break
        diag = state["diag"] or {}
    finally:
        if replay_proc is not None and replay_proc.poll() is None:
            replay_proc.kill()
        if node_proc.poll() is None:
            node_proc.send_signal(signal.SIGINT)
            try:
                node_proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                node_proc.kill()
        node_log.close()
        rclpy.shutdown(context=context)

    # ---------------------------------------------------------------- DDS results
    got = received(diag) if diag else 0
    drops = {k.split(".", 1)[1]: int(v) for k, v in diag.items() if k.startswith("dropped.")}
    losses = {k: v for k, v in drops.items() if k in INPUT_LOSS_DROPS and v}
    print(f"[5/6] evaluating the node's outputs ({len(poses)} ~/pose messages received)")
    print(f"      published by the replay: {published} (total {total_published}, wall {replay_wall:.1f} s)")
    print(f"      received by the node:    {got} (inputs {int(diag.get('inputs', 0))} + empty clouds "
          f"{drops.get('empty_cloud', 0)}), observation updates {int(diag.get('observation_updates', 0))}, "
          f"resets {int(diag.get('resets', 0))}")
    print(f"      node drop counters: {drops or 'none'}")
    if got != total_published or losses or int(diag.get("resets", 0)):
        print(f"      FAIL: inputs lost or unused: published {total_published}, received {got}, losses {losses}")
        ok = False
    else:
        print("      OK: every published input reached the node and none was dropped "
              "(empty clouds carry no observation; ambiguous/merged associations are estimator decisions)")

    path = state["path"]
    if path is not None and len(path.poses):
        traj = np.array([(p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec, p.pose.position.x,
                          p.pose.position.y, _yaw(p.pose.orientation)) for p in path.poses])
    else:
        traj = np.array([(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, m.pose.pose.position.x,
                          m.pose.pose.position.y, _yaw(m.pose.pose.orientation)) for m in poses]).reshape(-1, 4)
    traj = traj[np.argsort(traj[:, 0], kind="stable")]
    cloud = state["landmarks"]
    cols = decode_message(cloud) if cloud is not None else {k: np.zeros(0) for k in
                                                            ("x", "y", "id", "cov_xx", "cov_xy", "cov_yy", "n_obs")}
    positions = np.stack([cols["x"], cols["y"]], axis=1).astype(float)
    n_obs = np.asarray(cols["n_obs"], dtype=int)
    confirmed = n_obs >= config.association.confirm_observations

    cov = np.zeros((len(positions), 2, 2))
    cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 0], cov[:, 1, 1] = (cols["cov_xx"], cols["cov_xy"], cols["cov_xy"],
                                                              cols["cov_yy"])
    node_map = LandmarkMap(np.asarray(cols["id"], dtype=int), positions, cov, n_obs, confirmed)

    offset = (config.sensor.offset_x, config.sensor.offset_y)
    dds = {"method": "online_em (ROS node over DDS)", "bag": str(bag), "params": str(params), "seed": args.seed,
           "replay_rate": args.rate, "initial_pose": initial.to_dict(),
           "n_landmarks": int(len(positions)), "n_confirmed_landmarks": int(confirmed.sum()),
           "messages": {"published": published, "published_total": total_published, "received_total": got,
                        "node_inputs": int(diag.get("inputs", 0)), "pose_messages_received": len(poses),
                        "observation_updates": int(diag.get("observation_updates", 0))},
           "node_drops": drops, "input_losses": losses, "replay_wall_s": replay_wall,
           "trajectory_source": "~/path (one pose per processed input)" if path is not None else "~/pose"}
    if inputs.landmarks is not None:
        dds["landmarks"] = landmark_metrics(positions[confirmed], inputs.landmarks,
                                            estimated_ids=node_map.ids[confirmed]).to_dict()
    if inputs.has_gps and len(traj):
        dds["trajectory"] = trajectory_metrics(traj[:, 0], sensor_points(traj[:, 1:4], offset),
                                               inputs.gps_times, inputs.gps_xy).to_dict()
    cli.write_trajectory(out / "trajectory.csv", traj)
    cli.write_landmarks(out / "landmarks.csv", node_map)
    cli.json_dump(out / "metrics.json", dds)
    cli.plot_map(out / "map.png", "online EM SLAM node (DDS replay): car_park", traj, positions, node_map.ids, confirmed,
                 inputs.landmarks, inputs.gps_xy, offset)

    # ---------------------------------------------------------------- offline run
    print("[6/6] offline runner on the same bag (no DDS)", flush=True)
    offline = cli.run_one(inputs, config, settings, "online_em", initial, out / "offline",
                          extra={"params": str(params)})

    def lm(m, key, digits=3):
        v = (m.get("landmarks") or {}).get(key)
        return "n/a" if v is None else (f"{v:.{digits}f}" if isinstance(v, float) else str(v))

    def tr(m, key):
        v = (m.get("trajectory") or {}).get(key)
        return "n/a" if v is None else f"{v:.3f}"

    print("\nCar Park, online EM SLAM: node over DDS vs offline runner (same bag, params, seed, initial pose)")
    _print_table([
        ("beacons mapped (of 15)", lm(dds, "n_matched"), lm(offline, "n_matched")),
        ("spurious landmarks", lm(dds, "n_spurious"), lm(offline, "n_spurious")),
        ("beacon RMSE (m)", lm(dds, "rmse"), lm(offline, "rmse")),
        ("trajectory RMSE vs GPS (m)", tr(dds, "rmse"), tr(offline, "rmse")),
        ("trajectory median (m)", tr(dds, "median"), tr(offline, "median")),
        ("landmarks (confirmed)", f"{dds['n_landmarks']} ({dds['n_confirmed_landmarks']})",
         f"{offline['n_landmarks']} ({offline['n_confirmed_landmarks']})"),
        ("wall time (s)", f"{replay_wall:.1f}", f"{offline['timing']['wall_time_s']:.1f}"),
    ])
    off_lm = np.loadtxt(out / "offline" / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    if len(off_lm) == len(positions) and len(positions):
        order = np.argsort(node_map.ids)
        diff = np.abs(off_lm[np.argsort(off_lm[:, 0]), 1:3] - positions[order]).max()
        print(f"\n  largest landmark coordinate difference DDS vs offline: {diff:.2e} m")
    print(f"\nwrote {out}/trajectory.csv, landmarks.csv, metrics.json, map.png (node) and {out}/offline/ (offline)")
    return 0 if ok else 1


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


if __name__ == "__main__":
    sys.exit(main())
