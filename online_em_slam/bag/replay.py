"""Lossless bag replay with rclpy (a stand-in for ``ros2 bag play`` where ros2cli is absent).

    online-em-slam-replay BAG [--rate R] [--topics T ...] [--wait-subscribers TOPIC:COUNT ...]
                          [--wait-timeout S] [--clock [HZ]] [--start-delay S] [--ack-timeout S]
                          [--loop] [--start-offset S] [--playback-duration S] [--remap OLD:=NEW ...]
                          [--exclude T ...] [--exclude-regex R] [--start-paused] [--no-input-check]

Raw CDR bytes from the bag (rosbags reader) are published unchanged through
publishers created with the real rclpy message classes (type names resolved with
importlib: 'sensor_msgs/msg/PointCloud2' -> sensor_msgs.msg.PointCloud2).  Timing
follows the bag's log times scaled by ``--rate`` (``--rate 0``: as fast as
possible); a message the middleware refuses (a reliable subscriber that does not keep
up has filled the KEEP_ALL history) is retried for up to ``--publish-timeout`` s, so a
slow subscriber holds the replay back (``publish_blocked_*`` in the summary) instead of
losing messages.  QoS: RELIABLE + KEEP_ALL so that nothing is dropped by a matched
reliable subscriber; topics recorded as TRANSIENT_LOCAL (/tf_static, latched
ground truth) are offered TRANSIENT_LOCAL.  ``--clock`` publishes
rosgraph_msgs/Clock on /clock with the log time before each message (``--clock
HZ``: at HZ).  The options that follow ``ros2 bag play`` (loop, offset, duration,
remap, exclude, start paused) are described in :mod:`online_em_slam.bag.replay_options`.

At the end the number of messages published per topic is printed, followed by
one JSON line ``{"published": {...}, "skipped_topics": {...}, ...}`` on stdout.
Topics whose message package is not importable are skipped with a one-line warning
and listed under ``skipped_topics``; tf2_msgs (/tf, /tf_static), which is not on PyPI,
is first built into the environment (once, about 30 s; :mod:`online_em_slam.messages.tf2_build`).

A bad bag gets one line ``online-em-slam-replay: error: BAG: what is wrong`` on
stderr and exit status 1, before any publisher exists (:func:`check_bag`): not a
bag, unreadable, no messages, a replayed topic whose published name the node reads
with another message type (``/odom`` as std_msgs/String; leave it out with
``--exclude``) or a topic recorded with two types, and, unless ``--no-input-check``,
no motion input (/odom, /control) or no /landmark_observations.  A fleet bag
(``online-em-slam-convert mrclam --all-robots``: ``/robot1/odom``, ...) passes when
some robot namespace carries both (:func:`robot_namespaces`), and its namespaced
inputs are type-checked as the root ones.  A bag that goes
bad while playing (a corrupt chunk) ends the replay the same way, after the summary.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

from ..messages.tf2_build import first_use
from . import replay_options
from .bagio import (BagError, absolute_topic, bag_error, check_bag_path, is_latched, node_topic_types,
                    type_problems)


def message_class(msgtype: str):
    """'pkg/msg/Type' (or 'pkg/Type') -> the rclpy message class."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"bad message type name {msgtype!r}")
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
    except ImportError:
        # tf2_msgs is not on PyPI: in a wheels-only environment it is built here on first use.
        if parts[0] != "tf2_msgs" or not first_use.ensure(log=lambda line: print(line, file=sys.stderr, flush=True)):
            raise
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
    return getattr(module, parts[2])


def parse_wait(specs) -> dict[str, int]:
    out = {}
    for spec in specs or ():
        topic, sep, count = spec.rpartition(":")
        if not sep or not topic:
            topic, count = spec, "1"
        try:
            out[topic] = int(count)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--wait-subscribers expects TOPIC:COUNT, got {spec!r}") from None
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="online-em-slam-replay",
                                description="Replay a ROS 2 bag losslessly with rclpy (raw CDR).")
    p.add_argument("bag", help="bag directory (mcap or sqlite3)")
    p.add_argument("--rate", type=float, default=1.0, help="time scale (2 = twice as fast; 0 = no waiting)")
    p.add_argument("--topics", nargs="+", default=None, help="only these topics")
    p.add_argument("--wait-subscribers", nargs="+", default=[], metavar="TOPIC:COUNT",
                   help="before starting, wait until each topic has at least COUNT subscribers")
    p.add_argument("--wait-timeout", type=float, default=30.0, help="seconds to wait for subscribers")
    replay_options.add_arguments(p)      # --clock [HZ], --loop, --start-offset, --remap, ... (replay_options.py)
    p.add_argument("--start-delay", type=float, default=0.0, help="seconds to sleep after discovery")
    p.add_argument("--ack-timeout", type=float, default=10.0,
                   help="at the end, seconds to wait until reliable subscribers acknowledged everything")
    p.add_argument("--publish-timeout", type=float, default=60.0,
                   help="seconds to keep retrying a message the middleware refuses (a reliable subscriber "
                        "that does not keep up: the replay waits for it) before ending with an error")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--no-input-check", action="store_true",
                   help="replay a bag that lacks the node's motion or observation topic")
    return p


def check_bag(bag: Path, args) -> None:
    """Refuse (BagError, one line naming the bag) before any publisher exists: a bag rosbags cannot
    open, one without messages, a replayed topic published under a name the node reads but of
    another type (or of two types), and, unless --no-input-check, a bag without the node's motion
    input (odom or control) or observations as recorded (the node's default topic names; types are
    checked under the published names, after --remap)."""
    from rosbags.rosbag2 import Reader

    from ..parameters.specs import NodeSettings

    check_bag_path(bag)
    try:
        with Reader(bag) as reader:
            conns = [(c.topic, c.msgtype, c.msgcount, _chosen(args, c.topic)) for c in reader.connections]
    except Exception as error:  # noqa: BLE001 - rosbags raises many kinds on a bad file
        raise bag_error(bag, error) from None
    node = NodeSettings()
    expected = node_topic_types(node.odom_topic, node.control_topic, node.observations_topic)
    counts = {}
    for topic, _, n, _ in conns:
        counts[topic] = counts.get(topic, 0) + n
    motion = [absolute_topic(node.odom_topic), absolute_topic(node.control_topic)]
    observations = absolute_topic(node.observations_topic)
    namespaces = robot_namespaces(counts, motion, observations)
    inputs = {topic: expected[topic] for topic in (*motion, observations)}
    for ns in namespaces:             # a fleet bag: each robot's inputs have the node's types too
        expected.update({ns + topic: msgtype for topic, msgtype in inputs.items()})
    problems = type_problems([(replay_options.remap(args, topic), msgtype) for topic, msgtype, _, chosen in conns
                              if chosen], expected)
    if problems:
        raise BagError(f"{bag}: {'; '.join(problems)} (leave such a topic out with --exclude)")
    if not sum(counts.values()):
        raise BagError(f"{bag}: the bag holds no messages")
    if args.no_input_check or namespaces:
        return
    if not any(counts.get(t) for t in motion):
        raise BagError(f"{bag}: no motion input for the node: no messages on {' or '.join(motion)} "
                       "(--no-input-check replays it anyway)")
    if not counts.get(observations):
        raise BagError(f"{bag}: no observations for the node: no messages on {observations} "
                       "(--no-input-check replays it anyway)")


def robot_namespaces(counts: dict, motion, observations: str) -> list[str]:
    """The namespaces ``/NS`` of ``counts`` (topic -> messages) with messages on both ``/NS`` +
    ``observations`` and ``/NS`` + one of ``motion`` (absolute names): the robots of a fleet bag."""
    found = []
    for topic, n in counts.items():
        ns = topic[:-len(observations)]
        if n and ns and topic.endswith(observations) and any(counts.get(ns + m) for m in motion):
            found.append(ns)
    return sorted(found)


def _chosen(args, topic: str) -> bool:
    """Whether ``topic`` is replayed (--topics, --exclude, --exclude-regex)."""
    return (args.topics is None or topic in args.topics) and replay_options.selected(args, topic)


def _guarded(bag, iterator):
    """``iterator`` with what the bag reader raises turned into a one-line BagError."""
    while True:
        try:
            item = next(iterator)
        except StopIteration:
            return
        except Exception as error:  # noqa: BLE001 - rosbags raises many kinds on a bad file
            raise bag_error(bag, error) from None
        yield item


def _publishers(node, reader, args, log):
    """One publisher per replayed topic, with the recorded type and latching; the
    connections to play, publishers, skipped topics (why), per-topic counts."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    conns = [c for c in reader.connections if _chosen(args, c.topic)]
    if args.topics:
        missing = sorted(set(args.topics) - {c.topic for c in reader.connections})
        if missing:
            log(f"replay: topics not in the bag: {', '.join(missing)}")
    publishers, skipped, counts = {}, {}, {}
    for conn in conns:
        if conn.topic in publishers or conn.topic in skipped:
            continue
        try:
            cls = message_class(conn.msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            skipped[conn.topic] = f"{conn.msgtype}: {exc}"
            log(f"online-em-slam-replay: warning: {args.bag}: skipping {conn.topic}: {conn.msgtype} is not importable")
            continue
        latched = is_latched(conn) or conn.topic == "/tf_static"
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=100000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
        publishers[conn.topic] = node.create_publisher(cls, replay_options.remap(args, conn.topic), qos)
        counts[conn.topic] = 0
    return [c for c in conns if c.topic in publishers], publishers, skipped, counts


def _wait_for_subscribers(node, publishers, wait: dict, timeout: float, log) -> int:
    """0 when every topic reached its subscriber count in time, 3 otherwise (replay starts anyway).
    Discovery runs in the middleware's own threads, so plain sleeping is enough."""
    exit_code = 0
    deadline = time.monotonic() + timeout
    for topic, want in wait.items():
        def have(topic=topic):
            pub = publishers.get(topic)
            return pub.get_subscription_count() if pub is not None else node.count_subscribers(topic)
        while have() < want and time.monotonic() < deadline:
            time.sleep(0.02)
        if have() < want:
            log(f"replay: timeout: {topic} has {have()} of {want} subscribers; starting anyway")
            exit_code = 3
        else:
            log(f"replay: {topic} has {have()} subscriber(s)")
    return exit_code


class PublishError(RuntimeError):
    """The middleware refused a message for longer than --publish-timeout."""


def publish_waiting(publisher, raw: bytes, timeout: float, sleep=time.sleep, clock=time.monotonic) -> tuple[float, int]:
    """Publish ``raw``; while the middleware refuses it, wait and try again, for up to ``timeout`` s.

    A RELIABLE + KEEP_ALL writer whose history is full (a reliable subscriber that has not
    acknowledged: a node slower than the replay) blocks in Fast DDS for its max_blocking_time and
    then fails with "cannot publish data"; retrying lets the subscriber's pace hold the replay
    back instead of ending it.  (seconds waited, retries); PublishError after ``timeout``."""
    since, retries = clock(), 0
    while True:
        try:
            publisher.publish(raw)
            return (clock() - since if retries else 0.0), retries
        except RuntimeError as error:       # rclpy's RCLError
            if "cannot publish data" not in str(error):
                raise
            if clock() - since > timeout:
                raise PublishError(f"a subscriber acknowledged nothing for {timeout:g} s "
                                   f"(--publish-timeout): {error}") from None
            retries += 1
            sleep(0.005)


def _play(args, reader, conns, node, publishers, counts, log, blocked: dict) -> float:
    """Publish the raw messages paced by their log times (and /clock); the wall seconds taken.
    ``blocked``: the seconds and messages the middleware held back (publish_waiting), updated."""
    clock_pub, Clock = None, None
    if args.clock:
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    total = sum(c.msgcount for c in conns)
    start_wall = last_report = time.monotonic()
    bag_start = last_clock = None
    n = 0
    # replay_options.messages paces the messages (rate, pause, loop, offset) and sends /clock.
    for conn, log_time, raw in _guarded(args.bag, replay_options.messages(args, reader, conns, node, log)):
        bag_start = log_time if bag_start is None else bag_start
        if args.rate > 0:
            delay = start_wall + (log_time - bag_start) * 1e-9 / args.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        if clock_pub is not None and (last_clock is None or log_time > last_clock):
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(int(log_time), 1_000_000_000)
            clock_pub.publish(clock)
            last_clock = log_time
        waited, retries = publish_waiting(publishers[conn.topic], bytes(raw), args.publish_timeout)
        if retries:
            blocked["seconds"] += waited
            blocked["messages"] += 1
        counts[conn.topic] += 1
        n += 1
        now = time.monotonic()
        if now - last_report >= 1.0:
            last_report = now
            log(f"replay: {n}/{total} messages, bag time {(log_time - bag_start) * 1e-9:.1f} s, "
                f"wall {now - start_wall:.1f} s")
    return time.monotonic() - start_wall


def _acknowledged(publishers, timeout: float, log) -> bool:
    """Whether reliable subscribers acknowledged every message within ``timeout`` seconds."""
    from rclpy.duration import Duration
    acked = True
    for pub in publishers.values():
        if pub.get_subscription_count() > 0:
            acked &= bool(pub.wait_for_all_acked(Duration(seconds=timeout)))
    if not acked:
        log("replay: not every message was acknowledged within --ack-timeout")
    return acked


def _main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        wait = parse_wait(args.wait_subscribers)
    except argparse.ArgumentTypeError as exc:
        print(f"online-em-slam-replay: error: {exc}", file=sys.stderr)
        return 2
    bag = Path(args.bag)
    try:
        check_bag(bag, args)
    except (BagError, FileNotFoundError) as error:
        print(f"online-em-slam-replay: error: {error}", file=sys.stderr)
        return 1
    import rclpy
    from rosbags.rosbag2 import Reader

    def log(text: str) -> None:
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    # Not sys.argv: rcl would read --remap's OLD:=NEW as its deprecated remap syntax and warn
    # (every option is ours; argparse refuses --ros-args).
    rclpy.init(args=["online-em-slam-replay"])
    node = rclpy.create_node("bag_replay")
    counts, skipped, elapsed, acked, exit_code = {}, {}, None, False, 0
    blocked = {"seconds": 0.0, "messages": 0}
    started = time.monotonic()
    try:
        with Reader(bag) as reader:
            conns, publishers, skipped, counts = _publishers(node, reader, args, log)
            exit_code = _wait_for_subscribers(node, publishers, wait, args.wait_timeout, log)
            if args.start_delay > 0:
                time.sleep(args.start_delay)
            elapsed = _play(args, reader, conns, node, publishers, counts, log, blocked)
            acked = _acknowledged(publishers, args.ack_timeout, log)
    except KeyboardInterrupt:
        exit_code = 130
        elapsed = time.monotonic() - started       # stopped: the wall time until then
    except (BagError, PublishError) as error:     # the bag went bad while playing; a subscriber stopped
        print(f"online-em-slam-replay: error: {error}", file=sys.stderr)
        exit_code = 1
    except RuntimeError:
        # SIGINT inside an rclpy call (a publish, the wait for acknowledgements): rclpy's handler
        # shuts the context down first, and the call fails on it instead of being interrupted.
        if rclpy.ok():
            raise
        exit_code = 130
        elapsed = time.monotonic() - started
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    for topic, c in counts.items():
        print(f"{topic:32s} {c:8d}")
    print(json.dumps({"published": counts, "total": sum(counts.values()), "skipped_topics": skipped,
                      "wall_seconds": None if elapsed is None else round(elapsed, 3), "acknowledged": acked,
                      "publish_blocked_seconds": round(blocked["seconds"], 3),
                      "publish_blocked_messages": blocked["messages"],
                      "interrupted": exit_code == 130}), flush=True)
    return exit_code


def main(argv=None) -> int:
    """``online-em-slam-replay``; Ctrl-C at any point ends it with status 130, without a traceback."""
    try:
        return _main(argv)
    except KeyboardInterrupt:                 # stopped while starting: the summary, nothing published
        print(json.dumps({"published": {}, "total": 0, "skipped_topics": {}, "wall_seconds": None,
                          "acknowledged": False, "interrupted": True}), flush=True)
        return 130


if __name__ == "__main__":
    sys.exit(main())
