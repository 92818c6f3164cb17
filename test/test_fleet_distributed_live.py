"""The distributed fleet over DDS (issue 25 item 3): one node process per robot (``local_robot``),
sharing the map through their segment messages (ros/segment_link.py), fed simulated inputs from
this process.  Every node ends with every landmark, the nodes' maps agree up to the timing of
the messages, and they agree with the fleet run in one process; a node that starts after
another robot has finished gets that robot's segments from the topic's history."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from ros_domain import claim

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import TwistStamped  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from online_em_slam.core import FleetSlam  # noqa: E402
from online_em_slam.experiments.simulation import (ScenarioConfig, feed, fleet_scenarios,  # noqa: E402
                                                   slam_config_for)
from online_em_slam.ros import conversions as conv  # noqa: E402
from online_em_slam.ros.qos import latched_qos  # noqa: E402
from test_fleet import _Robot  # noqa: E402
from test_node import T0, landmark_table  # noqa: E402
from test_node_fleet import _model  # noqa: E402

pytestmark = pytest.mark.live
N_STEPS = 120
PARTICLES = 30


class _Nodes:
    """Node processes ``slam_<robot>`` driving one robot each, and this process's publishers,
    map and /diagnostics subscriptions (``maps``, ``diags`` by robot)."""

    def __init__(self, robots, scenarios, logs) -> None:
        self.robots, self.scenarios, self.logs = robots, scenarios, logs
        self.procs: dict = {}
        self.published = dict.fromkeys(robots, 0)
        self.maps, self.diags = {}, {}
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("distributed_fleet_test", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        self.pubs = {r: (self.node.create_publisher(TwistStamped, f"/{r}/control", qos),
                         self.node.create_publisher(PointCloud2, f"/{r}/landmark_observations", qos))
                     for r in robots}
        for r in robots:
            self.node.create_subscription(PointCloud2, f"/slam_{r}/landmarks",
                                          lambda m, r=r: self.maps.__setitem__(r, landmark_table(m)), latched_qos())
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 100)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diags[status.name.split(":")[0].removeprefix("slam_")] = {kv.key: kv.value for kv in status.values}

    def start(self, robots) -> None:
        poses = ", ".join(f"{v:.9f}" for s in self.scenarios for v in s.initial_pose)
        params = {"robots": f"[{', '.join(self.robots)}]", "initial_poses": f"[{poses}]",
                  "motion_source": "control", "control_angular": "steering", "filter.num_particles": PARTICLES,
                  "filter.seed": 0, "input_qos.reliability": "reliable", "input_delay": 1.0,
                  "map_publish_period": 0.1, "diagnostics_period": 0.2, **_model(self.scenarios[0].config)}
        for robot in robots:
            cmd = [sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "-r", f"__node:=slam_{robot}",
                   "-p", f"local_robot:={robot}"]
            for key, value in params.items():
                cmd += ["-p", f"{key}:={str(value).lower() if isinstance(value, bool) else value}"]
            log = open(self.logs / f"{robot}.log", "w")
            self.procs[robot] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True,
                                                 env=dict(os.environ))
        ready = lambda: all(self.pubs[r][0].get_subscription_count() and self.pubs[r][1].get_subscription_count()
                            for r in robots) \
            and self.node.count_publishers("/fleet/map_segments") >= len(self.procs)   # noqa: E731
        assert self.spin_until(ready, 60.0), "the nodes did not come up"

    def spin_until(self, condition, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
            assert all(p.poll() is None for p in self.procs.values()), self.log_text()
        return condition()

    def publish(self, robots) -> None:
        """Every step of ``robots``' inputs, paced as a robot's streams are (about 40x real time)."""
        for k in range(N_STEPS):
            for r in robots:
                step = self.scenarios[self.robots.index(r)].steps[k]
                msg = TwistStamped(header=Header(stamp=conv.sec_to_stamp(T0 + step.control_stamp),
                                                 frame_id=f"{r}/base_link"))
                msg.twist.linear.x, msg.twist.angular.z = (float(v) for v in step.control)
                self.pubs[r][0].publish(msg)
                self.pubs[r][1].publish(conv.observations_to_cloud(
                    Header(stamp=conv.sec_to_stamp(T0 + step.stamp), frame_id=f"{r}/sensor"),
                    step.ranges, step.bearings, step.ids))
                self.published[r] += 2 if len(step.ranges) else 1
            self.executor.spin_once(timeout_sec=0.005)
            time.sleep(0.005)

    def settled(self) -> bool:
        """Every running node has used every input of its robot and folded every segment sent."""
        d = [self.diags.get(r) for r in self.procs]
        if any(x is None or x.get(f"inputs.{r}") != str(self.published[r]) or x.get("queued_inputs") != "0"
               for x, r in zip(d, self.procs)):
            return False
        sent = sum(int(x["segments.sent"]) for x in d)
        return all(int(x["segments.folded"]) + int(x["segments.sent"]) == sent for x in d)

    def wait_settled(self) -> None:
        assert self.spin_until(self.settled, 90.0), json.dumps(self.diags)[-3000:] + self.log_text()
        assert self.spin_until(lambda: len(self.maps) == len(self.procs), 10.0)
        time.sleep(0.3)
        self.spin_until(lambda: False, 0.5)            # the maps published after the last fold

    def log_text(self) -> str:
        return "".join(f"\n--- {p.name}\n" + p.read_text()[-3000:] for p in sorted(self.logs.glob("*.log")))

    def close(self) -> None:
        for p in self.procs.values():
            p.terminate()
        for p in self.procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        rclpy.shutdown(context=self.context)


def _fleet_in_one_process(scenarios, order) -> dict:
    """The fleet in one process fed in ``order``: (step, robot) pairs."""
    config = slam_config_for(scenarios[0], num_particles=PARTICLES, seed=0)
    fleet = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    for k, r in order:
        feed(_Robot(fleet, r), scenarios[r].steps[k])
    lm = fleet.landmarks(confirmed_only=True)
    return dict(zip(lm.ids.tolist(), lm.positions))


def _check(nodes: _Nodes, joint: dict, to_fleet_limit: float, between_limit: float = 0.05) -> None:
    for r, d in nodes.diags.items():
        counts = {k: v for k, v in d.items() if k.startswith(("dropped", "segments", "resets"))}
        assert int(d["segments.sent"]) > 3 and d["segments.lost"] == "0" and d["resets"] == "0", counts
        assert not any(k.startswith("dropped.segment") for k in d), counts
    maps = nodes.maps
    first = maps[nodes.robots[0]]
    assert all(set(m) == set(first) for m in maps.values()), {r: sorted(set(m) ^ set(first)) for r, m in maps.items()}
    assert set(joint) <= set(first), sorted(set(joint) - set(first))       # its confirmed landmarks
    between = max(math.dist(m[i], first[i]) for m in maps.values() for i in first)
    to_fleet = max(math.dist(first[i], joint[i]) for i in joint)
    print(f"{len(maps)} nodes: {len(first)} landmarks, between nodes {between:.2e} m, to the one-process "
          f"fleet {to_fleet:.3f} m")
    assert between < between_limit and to_fleet < to_fleet_limit
    assert np.isfinite([v for m in maps.values() for xy in m.values() for v in xy]).all()


@pytest.fixture
def discovery(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(claim()))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def test_five_nodes_driving_at_once_hold_one_map(discovery, tmp_path):
    robots = [f"robot{k + 1}" for k in range(5)]
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=N_STEPS, seed=0), 5)
    nodes = _Nodes(robots, scenarios, tmp_path)
    try:
        nodes.start(robots)
        nodes.publish(robots)
        nodes.wait_settled()
    finally:
        nodes.close()
    # Measured: between the nodes 0-0.014 m, once 0.0505 m on a loaded CI machine (the nodes fold
    # each other's segments in the order they arrive), to the one-process fleet 0.061-0.071 m.
    # Each node's map may differ from the one-process fleet's by up to 0.2 m, so two nodes' by
    # up to twice that; 0.1 m still catches a node that missed or misfolded a robot's segments.
    joint = _fleet_in_one_process(scenarios, [(k, r) for k in range(N_STEPS) for r in range(5)])
    _check(nodes, joint, 0.2, between_limit=0.1)


def test_a_node_started_after_another_robot_finished_gets_its_segments(discovery, tmp_path):
    """Robot 1 drives its whole run before robot 2's node starts: robot 2's node folds robot 1's
    segments from the topic's history (transient local) and both end with one map."""
    robots = ["robot1", "robot2"]
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=N_STEPS, seed=0), 2)
    nodes = _Nodes(robots, scenarios, tmp_path)
    try:
        nodes.start(["robot1"])
        nodes.publish(["robot1"])
        nodes.wait_settled()
        nodes.start(["robot2"])
        nodes.publish(["robot2"])
        nodes.wait_settled()
    finally:
        nodes.close()
    assert nodes.diags["robot2"]["segments.folded"] == nodes.diags["robot1"]["segments.sent"]
    # Robot 2's node folded every segment of robot 1 before its first input, as the fleet in one
    # process fed robot 1's run and then robot 2's: the same map (measured 0.000 m, the cloud's float32).
    order = [(k, 0) for k in range(N_STEPS)] + [(k, 1) for k in range(N_STEPS)]
    _check(nodes, _fleet_in_one_process(scenarios, order), 0.01)
