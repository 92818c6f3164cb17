"""``online-em-slam-record OUTBAG``: record the SLAM node's outputs, TF and inputs to a bag.

    online-em-slam-record OUTBAG [--topics T ...] [--all] [--node-name NAME] [--no-inputs]
                          [--storage mcap|sqlite3] [--duration S] [--use-sim-time]

A stand-in for ``ros2 bag record`` where rosbag2 is absent (PyPI wheels): rclpy
subscriptions deliver the serialized CDR bytes (``raw=True``) and the rosbags
writer stores them unchanged, so the bag is what ``ros2 bag record`` would
write (mcap by default; ``ros2 bag play`` and ``online-em-slam evaluate`` read it).

Topics by default: the node's outputs (``/NAME/pose``, ``path``, ``particles``,
``landmarks``, ``landmark_markers``, ``map_to_odom``), ``/tf``, ``/tf_static``,
``/diagnostics``, and its inputs with the ground truth of a converted bag
(``/odom``, ``/control``, ``/landmark_observations``, ``/scan``,
``/ground_truth/*``; ``--no-inputs`` leaves those out).  A topic is subscribed
once it has a publisher, with a QoS matching the publishers (latched topics are
received and stored as latched).  Types that cannot be imported here are
skipped with a message (``/tf`` needs tf2_msgs, built on first use where it is not
installed: docs/NODE.md).  The log time is
the receive time (the ROS clock with ``--use-sim-time``).  Ctrl-C, SIGTERM or
``--duration`` stop and close the bag; a per-topic count and one JSON line
``{"recorded": {...}, ...}`` are printed at the end.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

OUTPUT_TOPICS = ("pose", "path", "particles", "landmarks", "landmark_markers", "map_to_odom")
SHARED_TOPICS = ("/tf", "/tf_static", "/diagnostics")
INPUT_TOPICS = ("/odom", "/control", "/landmark_observations", "/scan",
                "/ground_truth/position", "/ground_truth/landmarks")


def default_topics(node_name: str = "online_em_slam", inputs: bool = True) -> list[str]:
    prefix = "/" + node_name.strip("/")
    topics = [f"{prefix}/{t}" for t in OUTPUT_TOPICS] + list(SHARED_TOPICS)
    return topics + list(INPUT_TOPICS) if inputs else topics


class Recorder:
    """Subscribes to topics as they appear and writes their raw messages to a rosbags writer."""

    def __init__(self, node, writer, topics: list[str] | None, log=print) -> None:
        from .bagio import jazzy_typestore

        self.node, self.writer, self.log = node, writer, log
        self.wanted = None if topics is None else list(topics)     # None: every topic
        self.typestore = jazzy_typestore()
        self.counts: dict[str, int] = {}
        self.skipped: dict[str, str] = {}
        self._subs: dict[str, object] = {}
        self._early: list = []                     # (connection, topic, raw) waiting for the first /clock

    def discover(self) -> None:
        """Subscribe to the wanted topics that have publishers now (call periodically)."""
        types = dict(self.node.get_topic_names_and_types())
        for topic in (self.wanted if self.wanted is not None else sorted(types)):
            if topic in self._subs or topic in self.skipped or not types.get(topic):
                continue
            self._subscribe(topic, types[topic][0])

    def _subscribe(self, topic: str, type_name: str) -> None:
        from .bagio import latched_qos
        from .replay import message_class
        from .topic_tool import matching_qos

        if type_name not in self.typestore.types:
            self.skipped[topic] = f"{type_name} unknown to the bag writer"
        else:
            try:
                cls = message_class(type_name)
            except (ImportError, AttributeError, ValueError):
                self.skipped[topic] = f"{type_name} not importable"
        if topic in self.skipped:
            self.log(f"record: skipping {topic} ({self.skipped[topic]})")
            return
        qos = matching_qos(self.node, topic, depth=1000)
        latched = qos.durability.name == "TRANSIENT_LOCAL"
        # Latched topics are stored with a latched offered QoS so that a replay latches them too.
        conn = self.writer.add_connection(topic, type_name, typestore=self.typestore,
                                          offered_qos_profiles=latched_qos() if latched else ())
        self.counts[topic] = 0

        def write(raw: bytes, conn=conn, topic=topic) -> None:
            self.store(conn, topic, raw)

        self._subs[topic] = self.node.create_subscription(cls, topic, write, qos, raw=True)
        self.log(f"record: {topic} [{type_name}]" + (" (latched)" if latched else ""))

    def store(self, conn, topic: str, raw: bytes) -> None:
        """Write one message at the node's time.  Under sim time, before the first /clock, the
        time is 0: such messages (latched start-up messages of a node started before the
        replay) wait and are written at the first clock time, so they come first in the bag
        rather than at a wall-clock stamp after the whole run."""
        now = self.node.get_clock().now().nanoseconds
        if now <= 0:
            self._early.append((conn, topic, raw))
            return
        self.flush_early(now)
        self.writer.write(conn, now, raw)
        self.counts[topic] += 1

    @property
    def holding(self) -> bool:
        """Messages wait for the first /clock."""
        return bool(self._early)

    def flush_early(self, stamp_ns: int | None = None) -> None:
        """Write the messages held for the first clock at ``stamp_ns`` (default: the node's time,
        or the wall clock when no /clock ever came)."""
        if not self._early:
            return
        if stamp_ns is None:
            now = self.node.get_clock().now().nanoseconds
            stamp_ns = now if now > 0 else time.time_ns()
        for conn, topic, raw in self._early:
            self.writer.write(conn, stamp_ns, raw)
            self.counts[topic] += 1
        self._early = []


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="online-em-slam-record",
                                description="Record the SLAM node's outputs, /tf and its inputs to a ROS 2 bag.")
    p.add_argument("output", help="bag directory to create")
    p.add_argument("--topics", nargs="+", default=None, help="record these topics instead of the defaults")
    p.add_argument("--all", action="store_true", help="record every topic that appears")
    p.add_argument("--node-name", default="online_em_slam", help="the SLAM node's name (output topic prefix)")
    p.add_argument("--no-inputs", action="store_true", help="only the node's outputs, /tf and /diagnostics")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    p.add_argument("--use-sim-time", action="store_true", help="log times from /clock")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def _topics(args) -> list[str] | None:
    if args.all:
        return None
    if args.topics:
        return ["/" + t.lstrip("/") for t in args.topics]
    return default_topics(args.node_name, inputs=not args.no_inputs)


def record(args, log) -> dict:
    """Run the recorder until stopped; returns the summary."""
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from rosbags.rosbag2 import StoragePlugin, Writer

    stop = []
    context = rclpy.Context()
    # Not sys.argv (every option is ours): rcl would parse any NAME:=VALUE in it as a remap.
    rclpy.init(args=["online-em-slam-record"], context=context, signal_handler_options=SignalHandlerOptions.NO)
    # Our own handlers: a signal ends the loop so that the bag is closed properly.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    node = rclpy.create_node("online_em_slam_record", context=context,
                             parameter_overrides=[Parameter("use_sim_time", value=bool(args.use_sim_time))])
    executor = _executor(context, node)
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[args.storage]
    started = time.monotonic()
    recorder = None
    try:
        with Writer(Path(args.output), version=9, storage_plugin=plugin) as writer:
            recorder = Recorder(node, writer, _topics(args), log)
            end = started + args.duration if args.duration > 0 else float("inf")
            next_discovery = 0.0
            while not stop and time.monotonic() < end:
                if time.monotonic() >= next_discovery:
                    recorder.discover()
                    next_discovery = time.monotonic() + 0.2
                executor.spin_once(timeout_sec=0.05)
                if recorder.holding and node.get_clock().now().nanoseconds > 0:
                    recorder.flush_early()           # the first /clock: the held messages at its time
            recorder.flush_early()
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
    return {"recorded": recorder.counts, "total": sum(recorder.counts.values()),
            "skipped_topics": recorder.skipped, "wall_seconds": round(time.monotonic() - started, 3)}


def _executor(context, node):
    # The events executor keeps up with a fast replay (about 3x the single-threaded one).
    try:
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor(context=context)
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    return executor


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if Path(args.output).exists():
        print(f"online-em-slam-record: error: {args.output} exists (give a new OUTPUT; a bag is never "
              "overwritten)", file=sys.stderr)
        return 1

    def log(text: str) -> None:
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    summary = record(args, log)
    for topic, n in sorted(summary["recorded"].items()):
        print(f"{topic:40s} {n:8d}")
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
