"""End-to-end demo on the bundled Car Park data: bag -> DDS -> node -> evaluation.

    python -m online_em_slam.experiments.demo [--output out/demo] [--rate 5] [--seed 0]

1. converts the bundled KTH Car Park data to a bag (``OUTPUT/car_park_bag``);
2. starts the SLAM node as a separate process (``python -m online_em_slam.ros.node``
   with ``config/car_park.yaml``, ``use_sim_time``, the initial pose from GPS);
3. records the node's ``~/pose``, ``~/path``, ``~/landmarks`` and ``/diagnostics``
   in this process (rclpy);
4. replays the bag as a third process (``python -m online_em_slam.bag.replay`` at
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
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

NODE_NAME = "online_em_slam"
INPUT_TOPICS = ("/control", "/odom", "/landmark_observations")
# Node drop reasons counted before an input enters its buffer (not in the "inputs" counter).
INPUTS_SILENT_AT_END = ("/control", "/landmark_observations", "/odom")
PRE_BUFFER_DROPS = ("empty_cloud", "malformed_cloud", "non_finite_odometry", "non_finite_control")
# Drops that would mean an input was lost or unused (must be zero in the demo).
INPUT_LOSS_DROPS = ("malformed_cloud", "non_finite_odometry", "non_finite_control", "non_finite_stamp",
                    "out_of_order", "zero_time_step", "no_motion_input", "paused", "internal_error",
                    "reapply_failed")


def find_params(name: str = "car_park.yaml") -> Path:
    """config/<name> of the source tree, else of the installed package share (ament_index
    on a ROS install, else <sys.prefix>/share/online_em_slam after a plain pip install)."""
    candidates = [Path(__file__).resolve().parents[2] / "config" / name]
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory("online_em_slam")) / "config" / name)
    except Exception:  # noqa: BLE001  (not importable, or AMENT_PREFIX_PATH unset)
        pass
    candidates.append(Path(sys.prefix) / "share" / "online_em_slam" / "config" / name)
    for path in candidates:
        if path.exists():
            return path
    raise FileNotFoundError(f"config/{name} not found in {', '.join(str(p) for p in candidates)}")


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


def _parse_args(argv):
    parser = argparse.ArgumentParser(prog="python -m online_em_slam.experiments.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--output", default="out/demo", help="output directory (default out/demo)")
    parser.add_argument("--params", default=None, help="node params file (default config/car_park.yaml)")
    parser.add_argument("--rate", type=float, default=5.0, help="replay rate (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="filter seed of the node and the offline run")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default 1 + pid %% 100)")
    parser.add_argument("--timeout", type=float, default=180.0, help="overall time limit of the DDS part (s)")
    return parser.parse_args(argv)


def _isolate_dds(domain_id) -> int:
    """A DDS domain of our own on this host; set before rclpy is imported, children inherit it."""
    domain = domain_id if domain_id is not None else 1 + os.getpid() % 100
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return domain


@dataclass
class Setup:
    """What the node run and the offline run share: the bag, its inputs and the settings."""

    bag: Path
    params: Path
    seed: int
    config: object
    settings: object
    inputs: object                         # runner.BagInputs
    initial: object                        # evaluation.InitialPose


def _prepare(bag: Path, params: Path, seed: int) -> Setup:
    """Step 1: the bag from the bundled data, its inputs and the initial pose from GPS."""
    from ..datasets.kth.convert import convert
    from ..parameters.yaml_file import config_from_params, load_params
    from ..offline.runner import choose_initial_pose, read_inputs

    print(f"[1/6] converting the bundled Car Park data to {bag}", flush=True)
    convert("car_park", bag, progress=False, overwrite=True)
    file_values = load_params(params)
    config, settings = config_from_params(file_values, {"filter.seed": seed})
    inputs = read_inputs(bag, settings)
    initial = choose_initial_pose("gps", inputs, config, settings, file_values)
    print(f"      initial pose from GPS: x={initial.x:.3f} y={initial.y:.3f} yaw={initial.yaw:.4f} "
          f"({initial.source})", flush=True)
    return Setup(bag, params, seed, config, settings, inputs, initial)


def _start_node(setup: Setup, out: Path, domain: int):
    """Step 2: the SLAM node as a separate process, at the GPS initial pose; returns (process, log file)."""
    initial = setup.initial
    node_log = open(out / "node.log", "w")
    node_cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file", str(setup.params),
                "-p", "use_sim_time:=true", "-p", f"filter.seed:={setup.seed}",
                "-p", f"initial_pose.x:={initial.x:.9f}", "-p", f"initial_pose.y:={initial.y:.9f}",
                "-p", f"initial_pose.yaw:={initial.yaw:.12f}", "-p", "publish_particles:=false",
                # The trajectory error is computed from ~/path: publish every kept pose, not a decimation.
                "-p", "path_publish_max_poses:=20000"]
    print(f"[2/6] starting the node (ROS_DOMAIN_ID={domain}): {' '.join(node_cmd[1:])}", flush=True)
    return subprocess.Popen(node_cmd, stdout=node_log, stderr=subprocess.STDOUT, env=dict(os.environ)), node_log


@dataclass
class Recording:
    """What the demo received from the node, and what the replay published."""

    poses: list = field(default_factory=list)         # ~/pose messages
    path: object = None                               # last ~/path
    landmarks: object = None                          # last ~/landmarks cloud
    diag: dict = field(default_factory=dict)          # last diagnostics of the node
    levels: list = field(default_factory=list)        # (level, message) of every status received
    published: dict = field(default_factory=dict)     # by input topic
    replay_wall: float = 0.0

    @property
    def total_published(self) -> int:
        return sum(self.published.values())

    def received(self) -> int:
        """Inputs the node accounted for: buffered ones and those dropped before the buffer."""
        diag = self.diag
        return int(diag.get("inputs", 0)) + sum(int(diag.get(f"dropped.{r}", diag.get(f"decided.{r}", 0)))
                                                for r in PRE_BUFFER_DROPS)

    def on_diagnostics(self, msg) -> None:
        for status in msg.status:
            if status.name.startswith(f"{NODE_NAME}:"):
                self.diag = _diag_values(status)
                self.levels.append((int.from_bytes(status.level, "little") if isinstance(status.level, bytes)
                                    else int(status.level), status.message))


def _subscribe(rec, recording: Recording) -> None:
    """The recorder's subscriptions to the node's outputs (latched ones with TRANSIENT_LOCAL)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Path as PathMsg
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pose_qos = QoSProfile(depth=10000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    rec.create_subscription(PoseWithCovarianceStamped, f"/{NODE_NAME}/pose", recording.poses.append, pose_qos)
    rec.create_subscription(PathMsg, f"/{NODE_NAME}/path", lambda m: setattr(recording, "path", m), latched)
    rec.create_subscription(PointCloud2, f"/{NODE_NAME}/landmarks", lambda m: setattr(recording, "landmarks", m),
                            latched)
    rec.create_subscription(DiagnosticArray, "/diagnostics", recording.on_diagnostics, QoSProfile(depth=50))


def _replay(executor, node_proc, bag: Path, rate: float, deadline: float, out: Path, recording: Recording):
    """Step 3: replay the bag as a third process, spinning the recorder meanwhile."""
    replay_cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", str(rate), "--clock",
                  "--wait-subscribers", "/control:1", "/odom:1", "/landmark_observations:1", "/clock:1",
                  "--wait-timeout", "60", "--quiet"]
    print(f"[3/6] replaying at rate {rate:g} (~{125 / max(rate, 1e-9):.0f} s): {' '.join(replay_cmd[1:])}",
          flush=True)
    started = time.monotonic()
    proc = subprocess.Popen(replay_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if node_proc.poll() is not None:
                raise RuntimeError(f"the node exited early (code {node_proc.returncode}); see {out / 'node.log'}")
        if proc.poll() is None:
            raise RuntimeError("replay did not finish in time")
        replay_out, replay_err = proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
    recording.replay_wall = time.monotonic() - started
    if proc.returncode != 0:
        raise RuntimeError(f"replay failed (code {proc.returncode}): {replay_err.strip()}")
    summary = json.loads(replay_out.strip().splitlines()[-1])
    recording.published = {t: int(summary["published"].get(t, 0)) for t in INPUT_TOPICS}


def _wait_for_node(executor, recording: Recording, settings, deadline: float) -> None:
    """Step 4: until every input is accounted for (or nothing changed for a while: inputs lost),
    then a settle time for the final map and path publication."""
    print("[4/6] waiting for the node to process the last inputs", flush=True)
    settle = 2.5 * max(settings.map_publish_period, settings.diagnostics_period)
    settle_until, last_seen, last_change = None, None, time.monotonic()
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        diag = recording.diag
        if not diag:
            continue
        seen = (recording.received(), int(diag.get("observation_updates", 0)))
        if seen != last_seen:
            last_seen, last_change = seen, time.monotonic()
        idle = int(diag.get("queued_inputs", 1)) == 0
        if idle and (recording.received() >= recording.total_published
                     or time.monotonic() - last_change > 3 * settle):
            if settle_until is None:
                settle_until = time.monotonic() + settle
            elif time.monotonic() > settle_until:
                return


def _stop(proc) -> None:
    """SIGINT (a clean shutdown of the node), then kill if it does not exit."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _record_node_run(setup: Setup, out: Path, domain: int, rate: float, timeout: float) -> Recording:
    """Steps 2-4: node process, recorder in this process (own rclpy context), replay process."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    node_proc, node_log = _start_node(setup, out, domain)
    context = Context()
    rclpy.init(context=context)
    recording = Recording()
    try:
        rec = rclpy.create_node("demo_recorder", context=context)
        _subscribe(rec, recording)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(rec)
        deadline = time.monotonic() + timeout
        _replay(executor, node_proc, setup.bag, rate, deadline, out, recording)
        _wait_for_node(executor, recording, setup.settings, deadline)
    finally:
        _stop(node_proc)
        node_log.close()
        rclpy.shutdown(context=context)
    return recording


def _node_drops(recording: Recording) -> tuple[dict, dict]:
    """The node's drop counters, and those of them that mean an input was lost or unused."""
    drops = {k.split(".", 1)[1]: int(v) for k, v in recording.diag.items() if k.startswith(("dropped.", "decided."))}
    return drops, {k: v for k, v in drops.items() if k in INPUT_LOSS_DROPS and v}


def _check_inputs(recording: Recording) -> bool:
    """Step 5a: did every published input reach the node, unused by none?"""
    diag, got, total = recording.diag, recording.received(), recording.total_published
    drops, losses = _node_drops(recording)
    print(f"[5/6] evaluating the node's outputs ({len(recording.poses)} ~/pose messages received)")
    print(f"      published by the replay: {recording.published} (total {total}, "
          f"wall {recording.replay_wall:.1f} s)")
    print(f"      received by the node:    {got} (inputs {int(diag.get('inputs', 0))} + empty clouds "
          f"{drops.get('empty_cloud', 0)}), observation updates {int(diag.get('observation_updates', 0))}, "
          f"resets {int(diag.get('resets', 0))}")
    print(f"      node drop counters: {drops or 'none'}")
    warned = [message for level, message in recording.levels if level != 0]
    at_end = [m for m in warned if "silent inputs" in m and all(t in m for t in INPUTS_SILENT_AT_END)]
    print(f"      /diagnostics: {len(recording.levels) - len(warned)} of {len(recording.levels)} statuses OK"
          + (f", {len(at_end)} after the bag ended (every input silent)" if at_end else "")
          + (f"; otherwise not OK: {sorted(set(warned) - set(at_end))[:3]}" if len(warned) > len(at_end) else ""))
    if got != total or losses or int(diag.get("resets", 0)):
        print(f"      FAIL: inputs lost or unused: published {total}, received {got}, losses {losses}")
        return False
    print("      OK: every published input reached the node and none was dropped "
          "(empty clouds carry no observation; ambiguous/merged associations are estimator decisions)")
    return True


def _node_trajectory(recording: Recording) -> np.ndarray:
    """(n, 4) t, x, y, yaw from ~/path (every kept pose), else from the ~/pose messages."""
    from ..messages.quaternion import quaternion_to_yaw

    def row(stamp, pose):
        return (stamp.sec + 1e-9 * stamp.nanosec, pose.position.x, pose.position.y,
                quaternion_to_yaw(pose.orientation))

    if recording.path is not None and len(recording.path.poses):
        traj = np.array([row(p.header.stamp, p.pose) for p in recording.path.poses])
    else:
        traj = np.array([row(m.header.stamp, m.pose.pose) for m in recording.poses]).reshape(-1, 4)
    return traj[np.argsort(traj[:, 0], kind="stable")]


def _node_map(cloud, confirm_observations: int):
    """The node's last ~/landmarks cloud as a LandmarkMap (empty without one)."""
    from ..messages.cloud import decode_message
    from ..core.types import LandmarkMap

    cols = decode_message(cloud) if cloud is not None else {k: np.zeros(0) for k in
                                                            ("x", "y", "id", "cov_xx", "cov_xy", "cov_yy", "n_obs")}
    positions = np.stack([cols["x"], cols["y"]], axis=1).astype(float)
    n_obs = np.asarray(cols["n_obs"], dtype=int)
    cov = np.zeros((len(positions), 2, 2))
    cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 0], cov[:, 1, 1] = (cols["cov_xx"], cols["cov_xy"], cols["cov_xy"],
                                                              cols["cov_yy"])
    return LandmarkMap(np.asarray(cols["id"], dtype=int), positions, cov, n_obs, n_obs >= confirm_observations)


def _node_metrics(recording: Recording, setup: Setup, rate: float, traj: np.ndarray, node_map) -> dict:
    """metrics.json of the node run: message accounting, landmark and trajectory errors."""
    from ..offline.evaluation import landmark_metrics, sensor_points, trajectory_metrics

    inputs, diag = setup.inputs, recording.diag
    drops, losses = _node_drops(recording)
    confirmed = np.asarray(node_map.confirmed, dtype=bool)
    dds = {"method": "online_em (ROS node over DDS)", "bag": str(setup.bag), "params": str(setup.params),
           "seed": setup.seed, "replay_rate": rate, "initial_pose": setup.initial.to_dict(),
           "n_landmarks": int(len(node_map.ids)), "n_confirmed_landmarks": int(confirmed.sum()),
           "messages": {"published": recording.published, "published_total": recording.total_published,
                        "received_total": recording.received(), "node_inputs": int(diag.get("inputs", 0)),
                        "pose_messages_received": len(recording.poses),
                        "observation_updates": int(diag.get("observation_updates", 0))},
           "node_drops": drops, "input_losses": losses, "replay_wall_s": recording.replay_wall,
           "trajectory_source": ("~/path (one pose per processed input, the replays' poses up to their take-over)"
                                 if recording.path is not None else "~/pose")}
    if inputs.landmarks is not None:
        dds["landmarks"] = landmark_metrics(node_map.positions[confirmed], inputs.landmarks,
                                            estimated_ids=node_map.ids[confirmed]).to_dict()
    if inputs.has_gps and len(traj):
        offset = (setup.config.sensor.offset_x, setup.config.sensor.offset_y)
        dds["trajectory"] = trajectory_metrics(traj[:, 0], sensor_points(traj[:, 1:4], offset),
                                               inputs.gps_times, inputs.gps_xy).to_dict()
    return dds


def _write_node_outputs(out: Path, recording: Recording, setup: Setup, rate: float):
    """Step 5b: OUTPUT/{trajectory.csv, landmarks.csv, metrics.json, map.png} of the node run."""
    from ..offline.plots import plot_map
    from ..offline.report import json_dump, write_landmarks, write_trajectory

    traj = _node_trajectory(recording)
    node_map = _node_map(recording.landmarks, setup.config.association.confirm_observations)
    dds = _node_metrics(recording, setup, rate, traj, node_map)
    write_trajectory(out / "trajectory.csv", traj)
    write_landmarks(out / "landmarks.csv", node_map)
    json_dump(out / "metrics.json", dds)
    plot_map(out / "map.png", "online EM SLAM node (DDS replay): car_park", traj, node_map.positions,
             node_map.ids, node_map.confirmed, setup.inputs.landmarks, setup.inputs.gps_xy,
             (setup.config.sensor.offset_x, setup.config.sensor.offset_y))
    return dds, node_map


def _run_offline(setup: Setup, out: Path) -> dict:
    """Step 6: the offline runner (no DDS) on the same bag with the same settings."""
    from ..offline.runner import run_one

    print("[6/6] offline runner on the same bag (no DDS)", flush=True)
    return run_one(setup.inputs, setup.config, "online_em", setup.initial, out / "offline",
                   extra={"params": str(setup.params)})


def _print_comparison(dds: dict, offline: dict, node_map, out: Path, replay_wall: float) -> None:
    def lm(m, key, digits=3):
        v = (m.get("landmarks") or {}).get(key)
        return "n/a" if v is None else (f"{v:.{digits}f}" if isinstance(v, float) else str(v))

    def tr(m, key):
        # The node's ~/path holds the poses of the last replay up to its take-over: the offline run's
        # trajectory_revised, which the published trajectory is where no replay came.
        v = (m.get("trajectory_revised") or m.get("trajectory") or {}).get(key)
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
    positions = np.asarray(node_map.positions, dtype=float).reshape(-1, 2)
    off_lm = np.loadtxt(out / "offline" / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    if len(off_lm) == len(positions) and len(positions):
        order = np.argsort(node_map.ids)
        diff = np.abs(off_lm[np.argsort(off_lm[:, 0]), 1:3] - positions[order]).max()
        print(f"\n  largest landmark coordinate difference DDS vs offline: {diff:.2e} m")
    print(f"\nwrote {out}/trajectory.csv, landmarks.csv, metrics.json, map.png (node) and {out}/offline/ (offline)")


def main(argv=None) -> int:
    args = _parse_args(argv)
    domain = _isolate_dds(args.domain_id)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    params = Path(args.params) if args.params else find_params()
    setup = _prepare(out / "car_park_bag", params, args.seed)
    recording = _record_node_run(setup, out, domain, args.rate, args.timeout)
    ok = _check_inputs(recording)
    dds, node_map = _write_node_outputs(out, recording, setup, args.rate)
    offline = _run_offline(setup, out)
    _print_comparison(dds, offline, node_map, out, recording.replay_wall)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
