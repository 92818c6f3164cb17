"""Reading ROS 2 bags with rosbags (pure Python, no rclpy import).

Used by the offline runner and the tests: :func:`read_bag` yields deserialized
rosbags messages in log-time order with the stamp to use for each;
:func:`write_bag` writes a small MCAP bag from messages (the tests' bags).
"""
from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from .progress import Progress



def jazzy_typestore():
    """The rosbags type store of ROS 2 Jazzy's messages (bags written and read here)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)

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


def is_latched(conn) -> bool:
    """A bag connection offered as latched (TRANSIENT_LOCAL), from its QoS metadata."""
    from rosbags.interfaces import QosDurability
    profiles = getattr(conn.ext, "offered_qos_profiles", None) or []
    if isinstance(profiles, str):   # older metadata kept as YAML text
        return "durability: 1" in profiles or "transient_local" in profiles.lower()
    return any(getattr(p, "durability", None) == QosDurability.TRANSIENT_LOCAL for p in profiles)


def absolute_topic(topic: str) -> str:
    """``topic`` with a leading slash, as bag connections name topics."""
    return topic if topic.startswith("/") else "/" + topic


def latched_qos():
    """The offered QoS of a latched topic (TRANSIENT_LOCAL, depth 1), as /tf_static's."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    zero = QosTime(sec=0, nsec=0)
    return [Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                durability=QosDurability.TRANSIENT_LOCAL, deadline=zero, lifespan=zero,
                liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
                avoid_ros_namespace_conventions=False)]


def message_order(per_topic_ns: dict, priority: dict) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Time order of every message of a converter: per topic its stamps (ns) -> (stamps_ns, topics,
    index within topic), sorted by stamp, then ``priority[topic]`` (static data first, motion before
    sensing), then index."""
    topics = list(per_topic_ns)
    stamps = np.concatenate([per_topic_ns[t] for t in topics])
    prio = np.concatenate([np.full(len(per_topic_ns[t]), priority[t]) for t in topics])
    index = np.concatenate([np.arange(len(per_topic_ns[t])) for t in topics])
    order = np.lexsort((index, prio, stamps))
    names = sorted(priority, key=priority.get)
    return stamps[order], [names[p] for p in prio[order]], index[order]


def clear_bag_directory(output: Path, overwrite: bool) -> None:
    """Refuse an existing ``output`` unless ``overwrite`` and it is a bag (or empty); then remove it."""
    if not output.exists():
        return
    if not overwrite:
        raise FileExistsError(f"{output} exists (use --overwrite)")
    if not (output / "metadata.yaml").exists() and any(output.iterdir()):
        raise FileExistsError(f"{output} exists and does not look like a bag; not removing it")
    shutil.rmtree(output)


def write_topics(output, messages, counts: dict, msgtypes: dict, latched, typestore, storage: str = "mcap",
                 label: str = "", progress: bool = True, stream=None) -> dict[str, int]:
    """A converter's bag: one connection per topic of ``counts`` (messages expected per topic; in
    the order of ``msgtypes``), latched ones offered TRANSIENT_LOCAL, then ``messages``
    (stamp_ns, topic, msgtype, message) written in order; returns messages written per topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    written = {t: 0 for t in counts}
    bar = Progress(sum(counts.values()), label, stream=stream, enabled=progress)
    with Writer(output, version=9, storage_plugin=plugin) as writer:
        order = list(msgtypes)
        conns = {topic: writer.add_connection(topic, msgtypes[topic], typestore=typestore,
                                              offered_qos_profiles=latched_qos() if topic in latched else ())
                 for topic in sorted(counts, key=order.index)}
        for stamp, topic, msgtype, msg in messages:
            writer.write(conns[topic], stamp, typestore.serialize_cdr(msg, msgtype))
            written[topic] += 1
            bar.update()
    bar.close()
    return written


def check_bag_path(path) -> Path:
    """``path`` as a Path when it may be a bag; FileNotFoundError or BagError (one line naming
    it) when it does not exist, is a directory without metadata.yaml or a file of no bag kind."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: does not exist")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        raise BagError(f"{path}: not a bag: the directory has no metadata.yaml")
    if path.is_file() and path.suffix not in (".bag", ".mcap", ".db3"):
        raise BagError(f"{path}: not a bag: a plain file (a ROS 2 bag is a directory with metadata.yaml)")
    return path


def _open(path):
    from rosbags.highlevel import AnyReader
    return AnyReader([check_bag_path(path)], default_typestore=_typestore())


def bag_error(path, error: BaseException) -> Exception:
    """``error`` raised by rosbags on ``path`` as a one-line :class:`BagError` naming the bag
    (BagError and FileNotFoundError pass as they are)."""
    if isinstance(error, (BagError, FileNotFoundError)):
        return error
    first_line = (str(error).splitlines() or [""])[0]
    return BagError(f"{path}: cannot read the bag: {type(error).__name__}: {first_line}")


def normal_msgtype(name: str) -> str:
    """'pkg/Type' -> 'pkg/msg/Type' (other names unchanged)."""
    parts = str(name).split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else str(name)


def node_topic_types(odom: str = "odom", control: str = "control",
                     observations: str = "landmark_observations") -> dict[str, str]:
    """topic -> the message type the node and the offline tools read on it (absolute names)."""
    return {absolute_topic(odom): "nav_msgs/msg/Odometry",
            absolute_topic(control): "geometry_msgs/msg/TwistStamped",
            absolute_topic(observations): "sensor_msgs/msg/PointCloud2",
            "/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage",
            "/clock": "rosgraph_msgs/msg/Clock",
            "/ground_truth/position": "geometry_msgs/msg/PointStamped",
            "/ground_truth/pose": "geometry_msgs/msg/PoseStamped",
            "/ground_truth/landmarks": "sensor_msgs/msg/PointCloud2"}


def type_problems(connections: Iterable[tuple[str, str]], expected: dict[str, str]) -> list[str]:
    """What is wrong with the (topic, msgtype) connections of a bag against ``expected``
    (topic -> type): a topic recorded with two types, or with another type than expected."""
    types: dict[str, list[str]] = {}
    for topic, msgtype in connections:
        seen = types.setdefault(topic, [])
        if normal_msgtype(msgtype) not in seen:
            seen.append(normal_msgtype(msgtype))
    problems = []
    for topic, seen in types.items():
        want = expected.get(topic)
        if len(seen) > 1:
            problems.append(f"{topic} is recorded with {len(seen)} types ({', '.join(seen)})")
        elif want is not None and seen[0] != want:
            problems.append(f"{topic} is {seen[0]}, expected {want}")
    return problems


def bag_connections(path) -> list[tuple[str, str, int]]:
    """(topic, msgtype, message count) of every connection, from the bag's metadata."""
    try:
        with _open(path) as reader:
            return [(c.topic, c.msgtype, c.msgcount) for c in reader.connections]
    except Exception as error:  # noqa: BLE001 - rosbags raises many kinds on a bad file
        raise bag_error(path, error) from None


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
    except Exception as error:  # noqa: BLE001 - rosbags raises many kinds on a bad file
        raise bag_error(path, error) from None


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
    out: dict[str, tuple[str, int]] = {}
    for topic, msgtype, count in bag_connections(path):
        msgtype, n = out.get(topic, (msgtype, 0))
        out[topic] = (msgtype, n + count)
    return out


def count_messages(path, topics: Iterable[str] | None = None) -> Counter:
    """Count messages per topic by reading the bag (not trusting the metadata)."""
    return Counter(topic for topic, _, _ in read_bag(path, topics))
