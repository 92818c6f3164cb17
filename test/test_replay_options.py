"""online-em-slam-replay's ros2-bag-play options: window, loop, remap, exclude, /clock, start paused."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from online_em_slam.bag import replay_options as ro

S = 1_000_000_000


class FakeReader:
    """rosbags Reader stand-in: /tf_static at 0 s (latched), /a at 10 Hz and /b at 5 Hz for 2 s."""

    def __init__(self):
        ext = SimpleNamespace(offered_qos_profiles=[])
        self.connections = [SimpleNamespace(topic=t, ext=ext) for t in ("/tf_static", "/a", "/b")]
        tf, a, b = self.connections
        rows = [(tf, 0)] + [(a, k * S // 10) for k in range(20)] + [(b, k * S // 5 + 1) for k in range(10)]
        self.rows = sorted(rows, key=lambda r: r[1])
        self.start_time = 0

    def messages(self, connections=(), start=None, stop=None):
        for conn, t in self.rows:
            if (not connections or conn in connections) and (start is None or t >= start) \
                    and (stop is None or t < stop):
                yield conn, t, b"raw"


def _args(*argv):
    p = argparse.ArgumentParser()
    p.add_argument("--rate", type=float, default=0.0)
    ro.add_arguments(p)
    return p.parse_args(list(argv))


def _play(args, limit=None):
    reader = FakeReader()
    out = []
    for conn, t, _ in ro.messages(args, reader, reader.connections, node=None):
        out.append((conn.topic, t))
        if limit and len(out) >= limit:
            break
    return out


def test_window_keeps_latched_messages_before_the_offset():
    got = _play(_args("--start-offset", "1.0", "--playback-duration", "0.5"))
    assert got[0] == ("/tf_static", 0)
    times = [t for _, t in got[1:]]
    assert min(times) >= 1 * S and max(times) < 1.5 * S
    assert sum(1 for topic, _ in got if topic == "/a") == 5


def test_loop_repeats_and_rate_zero_does_not_wait():
    t0 = time.monotonic()
    got = _play(_args("--loop"), limit=3 * 31)
    assert time.monotonic() - t0 < 1.0
    assert [t for _, t in got[:31]] == [t for _, t in got[31:62]] == [t for _, t in got[62:]]


def test_pacing_follows_the_rate_and_takes_it_over():
    args = _args("--rate", "4", "--playback-duration", "1.0")
    t0 = time.monotonic()
    got = _play(args)
    assert args.rate == 0.0                         # the replay loop must not pace again
    assert 0.2 <= time.monotonic() - t0 < 0.5       # 1 s of bag at 4x
    assert len(got) == 1 + 10 + 5


def test_remap_exclude_and_clock_arguments():
    args = _args("--remap", "/a:=/x", "b:=/y", "--exclude", "/b", "--exclude-regex", "^/tf", "--clock", "25")
    assert ro.remap(args, "/a") == "/x" and ro.remap(args, "/b") == "/y" and ro.remap(args, "/c") == "/c"
    assert [ro.selected(args, t) for t in ("/a", "/b", "/tf_static")] == [True, False, False]
    assert (args.clock_hz, args.clock) == (25.0, False)
    assert _args("--clock").clock_hz == 0.0 and _args().clock_hz is None
    with pytest.raises(SystemExit):
        _args("--remap", "/a=/x")


def test_player_pause_freezes_bag_time():
    player = ro.Player(rate=1.0)
    player.start_pass(5 * S)
    time.sleep(0.1)
    player.set_paused(True)
    frozen = player.now_ns()
    time.sleep(0.1)
    assert player.now_ns() == frozen and 5.08 * S < frozen < 5.3 * S
    player.set_paused(False)
    time.sleep(0.05)
    assert player.now_ns() > frozen


# --------------------------------------------------------------------------- live replay

rclpy = pytest.importorskip("rclpy")

from ros_domain import claim  # noqa: E402

DOMAIN_ID = claim()


def test_live_replay_with_options(monkeypatch, tmp_path):
    """A bag replayed paused with remap, exclude, offset and --clock 50: nothing arrives
    until ~/resume, then the window on the new name, the excluded topic never, and /clock."""
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from geometry_msgs.msg import TwistStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    from test_replay import N_CONTROL, write_small_bag   # /control 200 Hz, 2 s from t = 10 s

    bag = tmp_path / "small"
    write_small_bag(bag)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ)
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    proc = None
    try:
        node = rclpy.create_node("options_sink", context=context)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        got, clouds, clock = [], [], []
        node.create_subscription(TwistStamped, "/ctl", got.append, reliable)
        node.create_subscription(PointCloud2, "/landmark_observations", clouds.append, reliable)
        node.create_subscription(Clock, "/clock", clock.append, 10)
        resume = node.create_client(Trigger, "/bag_replay/resume")
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        cmd = [sys.executable, "-m", "online_em_slam.bag.replay", str(bag), "--rate", "2", "--start-paused",
               "--remap", "/control:=/ctl", "--exclude", "/landmark_observations", "--start-offset", "1.0",
               "--clock", "50", "--wait-subscribers", "/control:1", "--quiet"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        assert resume.wait_for_service(timeout_sec=30)
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
        assert got == []                                  # paused
        future = resume.call_async(Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=10)
        assert future.result().success
        deadline = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.02)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        rclpy.shutdown(context=context)
    assert proc.returncode == 0, err
    assert "deprecated" not in err and "[rcl]" not in err, err     # --remap's OLD:=NEW is not rcl's (item 9)
    published = json.loads(out.strip().splitlines()[-1])["published"]
    assert "/landmark_observations" not in published and published["/control"] == N_CONTROL // 2
    assert len(got) == N_CONTROL // 2 and not clouds
    assert got[0].header.stamp.sec == 11                  # the second second of the bag
    stamps = [c.clock.sec + c.clock.nanosec * 1e-9 for c in clock]
    assert len(stamps) >= 10 and all(11.0 <= s <= 12.1 for s in stamps)   # ~0.5 s at 50 Hz
