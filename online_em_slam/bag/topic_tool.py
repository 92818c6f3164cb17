"""``online-em-slam-topic list|echo|hz``: a small ``ros2 topic`` for machines without ros2cli.

    online-em-slam-topic list [-t] [--spin-time S]
    online-em-slam-topic echo TOPIC [--once | --count N] [--timeout S] [--full-arrays]
    online-em-slam-topic hz TOPIC [--window N] [--duration S] [--timeout S]

The ROS 2 wheels from PyPI have rclpy but not ros2cli; on a real Jazzy install use
``ros2 topic list -t``, ``ros2 topic echo``, ``ros2 topic hz`` instead.  The
message type is taken from the ROS graph (the topic must have a publisher) and
imported from its Python package; the subscription's QoS follows the publishers
as ``ros2 topic echo`` does: TRANSIENT_LOCAL when every publisher is latched (so a
latched ``~/pose`` or ``~/landmarks`` is received at once), BEST_EFFORT when any
publisher is best effort.  Exit code 1 when nothing arrived before ``--timeout``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

#: Sequences longer than this are abbreviated by ``echo`` unless --full-arrays.
MAX_ARRAY = 64


# --------------------------------------------------------------------------- graph and QoS

def wait_for_type(node, topic: str, timeout: float) -> str | None:
    """The topic's type name once it appears in the graph (None after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while True:
        types = dict(node.get_topic_names_and_types())
        if types.get(topic):
            return types[topic][0]
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.05)      # discovery runs in the middleware's threads


def matching_qos(node, topic: str, depth: int = 100):
    """A subscription QoS that matches the topic's current publishers (as ros2 bag record)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    infos = node.get_publishers_info_by_topic(topic)
    latched = bool(infos) and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


# --------------------------------------------------------------------------- message -> YAML

def _is_message(value) -> bool:
    return hasattr(value, "get_fields_and_field_types")


def _scalar(value) -> str:
    if hasattr(value, "item"):            # numpy scalars from array fields
        value = value.item()
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else {True: ".inf", False: "-.inf"}.get(value > 0, ".nan")
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, bytes):
        return str(list(value))
    return str(value)


def message_to_yaml(msg, full_arrays: bool = False, indent: str = "") -> list[str]:
    """YAML lines for a message, in the layout of ``ros2 topic echo``."""
    lines = []
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if _is_message(value):
            lines.append(f"{indent}{name}:")
            lines.extend(message_to_yaml(value, full_arrays, indent + "  "))
        elif isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
            lines.append(f"{indent}{name}: {_scalar(value)}")
        else:
            lines.extend(_sequence_lines(name, list(value), full_arrays, indent))
    return lines


def _sequence_lines(name: str, items: list, full_arrays: bool, indent: str) -> list[str]:
    if not items:
        return [f"{indent}{name}: []"]
    shown = items if full_arrays or len(items) <= MAX_ARRAY else items[:MAX_ARRAY]
    if not _is_message(items[0]):
        more = "" if len(shown) == len(items) else f", '... {len(items)} elements'"
        return [f"{indent}{name}: [{', '.join(_scalar(v) for v in shown)}{more}]"]
    lines = [f"{indent}{name}:"]
    for item in shown:
        body = message_to_yaml(item, full_arrays, indent + "  ")
        lines.append(f"{indent}- {body[0].lstrip()}" if body else f"{indent}- {{}}")
        lines.extend(body[1:])
    if len(shown) < len(items):
        lines.append(f"{indent}- '... {len(items)} elements'")
    return lines


# --------------------------------------------------------------------------- commands

class _Session:
    """rclpy context, one node and an executor for the lifetime of a command."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(args=["online-em-slam-topic"], context=self.context)   # not sys.argv: the options are ours
        self.node = rclpy.create_node(f"online_em_slam_topic_{os.getpid()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, done, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() >= deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def _subscribe(session: _Session, args, callback, raw: bool = False):
    """Subscription to args.topic with the publisher's type and a matching QoS, or None."""
    from .replay import message_class

    type_name = wait_for_type(session.node, args.topic, args.timeout)
    if type_name is None:
        print(f"online-em-slam-topic: no publisher on {args.topic} within {args.timeout:g} s", file=sys.stderr)
        return None
    try:
        cls = message_class(type_name)
    except (ImportError, AttributeError, ValueError):
        print(f"online-em-slam-topic: message type {type_name} is not importable here", file=sys.stderr)
        return None
    qos = matching_qos(session.node, args.topic)
    return session.node.create_subscription(cls, args.topic, callback, qos, raw=raw)


def cmd_list(args, session: _Session) -> int:
    time.sleep(args.spin_time)            # let discovery fill in the graph
    for topic, types in sorted(session.node.get_topic_names_and_types()):
        print(f"{topic} [{', '.join(types)}]" if args.show_types else topic)
    return 0


def cmd_echo(args, session: _Session) -> int:
    count = 1 if args.once else args.count
    seen = [0]

    def on_message(msg) -> None:
        if count and seen[0] >= count:
            return
        seen[0] += 1
        print("\n".join(message_to_yaml(msg, args.full_arrays)) + "\n---", flush=True)

    if _subscribe(session, args, on_message) is None:
        return 1
    limit = args.timeout if count else math.inf
    session.spin_until(lambda: bool(count) and seen[0] >= count, limit)
    return 0 if seen[0] else 1


def rate_report(arrivals: list[float]) -> str | None:
    """The ``ros2 topic hz`` statistics of arrival times (s), None with fewer than two."""
    if len(arrivals) < 2:
        return None
    gaps = [b - a for a, b in zip(arrivals, arrivals[1:])]
    mean = sum(gaps) / len(gaps)
    std = math.sqrt(sum((g - mean) ** 2 for g in gaps) / len(gaps))
    rate = 1.0 / mean if mean > 0 else math.inf
    return (f"average rate: {rate:.3f}\n\tmin: {min(gaps):.3f}s max: {max(gaps):.3f}s "
            f"std dev: {std:.5f}s window: {len(arrivals)}")


def cmd_hz(args, session: _Session) -> int:
    arrivals: list[float] = []

    def on_message(_raw) -> None:
        arrivals.append(time.monotonic())
        del arrivals[:-args.window]

    # raw: measuring the rate needs no deserialisation.
    if _subscribe(session, args, on_message, raw=True) is None:
        return 1
    end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    printed = False
    while time.monotonic() < end:
        session.spin_until(lambda: False, min(1.0, max(end - time.monotonic(), 0.0)))
        report = rate_report(arrivals)
        print(report if report else "no new messages", flush=True)
        printed |= report is not None
    return 0 if printed else 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="online-em-slam-topic",
                                description="List, echo or measure ROS 2 topics (ros2 topic without ros2cli).")
    sub = p.add_subparsers(dest="command", required=True)
    ls = sub.add_parser("list", help="topics in the ROS graph")
    ls.add_argument("-t", "--show-types", action="store_true", help="also print each topic's type")
    ls.add_argument("--spin-time", type=float, default=2.0, help="seconds of discovery before listing")
    ls.set_defaults(func=cmd_list)
    echo = sub.add_parser("echo", help="print messages of a topic as YAML")
    echo.add_argument("topic")
    echo.add_argument("--once", action="store_true", help="print one message and exit")
    echo.add_argument("--count", type=int, default=0, help="exit after N messages (0: run until Ctrl-C)")
    echo.add_argument("--full-arrays", action="store_true", help=f"print arrays longer than {MAX_ARRAY} in full")
    echo.add_argument("--timeout", type=float, default=10.0,
                      help="seconds to wait for a publisher (and, with --once/--count, for the messages)")
    echo.set_defaults(func=cmd_echo)
    hz = sub.add_parser("hz", help="message rate of a topic")
    hz.add_argument("topic")
    hz.add_argument("--window", type=int, default=10000, help="arrivals kept for the statistics")
    hz.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    hz.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for a publisher")
    hz.set_defaults(func=cmd_hz)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if hasattr(args, "topic"):
        args.topic = "/" + args.topic.lstrip("/")      # relative names as ros2 topic takes them
    session = _Session()
    try:
        return args.func(args, session)
    except KeyboardInterrupt:
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
