"""Reading ROS 2 bags with rosbags (pure Python, no rclpy import).

Used by the offline runner and the tests: :func:`read_bag` yields deserialized
rosbags messages in log-time order with the stamp to use for each;
:func:`write_bag` writes a small MCAP bag from messages (the tests' bags).
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Callable, Iterable, Iterator


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def message_stamp(msg, log_time_ns: int) -> float:
    """header.stamp in seconds when the message has a header, else the log time."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None:
        return stamp.sec + stamp.nanosec * 1e-9
    return log_time_ns * 1e-9


def write_bag(path, messages: Iterable[tuple[int, str, str, object]], typestore) -> int:
    """Write (log time ns, topic, type name, message) in the given order to an MCAP bag at ``path``,
    one connection per topic (made at its first message); returns the number written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    written = 0
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for log_time_ns, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
            writer.write(connections[topic], int(log_time_ns), typestore.serialize_cdr(msg, msgtype))
            written += 1
    return written


class BagError(ValueError):
    """A bag that cannot be read (not a bag, truncated, corrupt): names the bag and the problem."""


def _open(path):
    from rosbags.highlevel import AnyReader
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag {path} does not exist")
    return AnyReader([path], default_typestore=_typestore())


def read_bag(path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, float, object]]:
    """Yield (topic, stamp_seconds, message) in log-time order.

    ``stamp_seconds`` is the header stamp when the message has one (the dataset
    time), otherwise the log time.  ``topics`` restricts the topics read (all by
    default).  Message definitions stored in the bag are used for types that the
    Jazzy typestore does not know.  One message at a time is held: a bag of any
    size streams.
    """
    for topic, stamp, msg, _ in read_bag_timed(path, topics):
        yield topic, stamp, msg


def read_bag_timed(path, topics: Iterable[str] | None = None,
                   decode: Callable[[str], bool] | None = None) -> Iterator[tuple[str, float, object, float]]:
    """:func:`read_bag` with the log time: (topic, stamp_seconds, message, log_time_seconds).

    ``decode(topic)``, asked per message, False: the message is not deserialized
    (yielded as None, stamped with its log time), for passes that only count.
    """
    try:
        yield from _read_timed(path, topics, decode)
    except (BagError, FileNotFoundError):
        raise
    except Exception as error:  # noqa: BLE001 - rosbags raises many kinds on a bad file
        first_line = (str(error).splitlines() or [""])[0]
        raise BagError(f"{path}: cannot read the bag: {type(error).__name__}: {first_line}") from None


def _read_timed(path, topics, decode):
    wanted = None if topics is None else set(topics)
    with _open(path) as reader:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        for conn, log_time, raw in reader.messages(connections=conns):
            if decode is not None and not decode(conn.topic):
                yield conn.topic, log_time * 1e-9, None, log_time * 1e-9
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            yield conn.topic, message_stamp(msg, log_time), msg, log_time * 1e-9


def bag_topics(path) -> dict[str, tuple[str, int]]:
    """topic -> (msgtype, message count) from the bag's metadata."""
    with _open(path) as reader:
        out: dict[str, tuple[str, int]] = {}
        for c in reader.connections:
            msgtype, n = out.get(c.topic, (c.msgtype, 0))
            out[c.topic] = (msgtype, n + c.msgcount)
        return out


def count_messages(path, topics: Iterable[str] | None = None) -> Counter:
    """Count messages per topic by reading the bag (not trusting the metadata)."""
    return Counter(topic for topic, _, _ in read_bag(path, topics))
