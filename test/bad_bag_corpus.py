"""Bad bags and parameter files for the offline tools (reliability, item 6).

``make_case(name, directory)`` writes one case under ``directory`` and returns
``(bag, params)``: the bag (or path) to give the tool and the parameter file for
``online-em-slam run``.  The good base is a small bag the Car Park parameter file
reads (``/control`` TwistStamped, ``/landmark_observations`` PointCloud2, ``/odom``
Odometry, ``/tf_static``), written with rosbags in mcap or sqlite3.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CAR_PARK_PARAMS = ROOT / "config" / "car_park.yaml"

N_CONTROL, N_CLOUDS, N_ODOM = 200, 20, 40
T0_NS = 10_000_000_000


def _messages(ts, topics, wrong: dict | None = None):
    """(ns, topic, msgtype, message) of the base bag for ``topics``; ``wrong`` maps a topic to the
    type it is written as instead (std_msgs/msg/String)."""
    from online_em_slam.messages.cloud import OBSERVATION_FIELDS, encode

    T = ts.types
    wrong = wrong or {}

    def header(ns, frame):
        sec, nsec = divmod(ns, 1_000_000_000)
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                        frame_id=frame)

    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    rng = np.random.default_rng(3)
    out = []
    for k in range(N_CONTROL):
        ns = T0_NS + k * 10_000_000
        twist = T["geometry_msgs/msg/Twist"](linear=V3(x=2.0, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.02))
        out.append((ns, 1, "/control", "geometry_msgs/msg/TwistStamped",
                    T["geometry_msgs/msg/TwistStamped"](header=header(ns, "base_link"), twist=twist)))
    for k in range(N_ODOM):
        ns = T0_NS + k * 50_000_000
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=0.1 * k, y=0.0, z=0.0),
                                           orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0))
        twist = T["geometry_msgs/msg/Twist"](linear=V3(x=2.0, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0))
        out.append((ns, 0, "/odom", "nav_msgs/msg/Odometry", T["nav_msgs/msg/Odometry"](
            header=header(ns, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))))
    for k in range(N_CLOUDS):
        ns = T0_NS + 5_000_000 + k * 100_000_000
        n = 3
        cols = {"x": rng.uniform(1, 20, n), "y": rng.uniform(-5, 5, n), "z": np.zeros(n),
                "range": rng.uniform(1, 20, n), "bearing": rng.uniform(-1, 1, n), "id": np.full(n, -1)}
        specs, step, data = encode(cols, layout=OBSERVATION_FIELDS)
        fields = [T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                  for f in specs]
        out.append((ns, 2, "/landmark_observations", "sensor_msgs/msg/PointCloud2", T["sensor_msgs/msg/PointCloud2"](
            header=header(ns, "laser"), height=1, width=n, fields=fields, is_bigendian=False, point_step=step,
            row_step=step * n, data=np.frombuffer(data, dtype=np.uint8).copy(), is_dense=True)))
    out = [e for e in out if e[2] in topics]
    string = T["std_msgs/msg/String"]
    out = [(ns, p, topic, "std_msgs/msg/String", string(data="not this type")) if topic in wrong
           else (ns, p, topic, msgtype, msg) for ns, p, topic, msgtype, msg in out]
    out.sort(key=lambda e: (e[0], e[1]))
    return [(ns, topic, msgtype, msg) for ns, _, topic, msgtype, msg in out]


BASE_TOPICS = ("/control", "/odom", "/landmark_observations")


def write_base(path: Path, topics=BASE_TOPICS, storage: str = "mcap", wrong: dict | None = None) -> Path:
    """The good small bag (or a variant with fewer topics, or some written as std_msgs/String)."""
    from collections import Counter

    from online_em_slam.bag.bagio import jazzy_typestore, write_topics

    ts = jazzy_typestore()
    messages = _messages(ts, topics, wrong)
    counts = Counter(topic for _, topic, _, _ in messages)
    msgtypes = {}
    for _, topic, msgtype, _ in messages:
        msgtypes.setdefault(topic, msgtype)
    write_topics(path, iter(messages), dict(counts), msgtypes, (), ts, storage=storage, progress=False)
    return path


def _storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


def _truncate(bag: Path, fraction: float) -> None:
    data = _storage_file(bag).read_bytes()
    _storage_file(bag).write_bytes(data[: int(len(data) * fraction)])


def _corrupt_chunk(bag: Path) -> None:
    """Set the length of the first record inside the first MCAP chunk to 2**64 - 1 (the
    chunks carry no CRC, so only the length gives it away)."""
    import struct

    path = _storage_file(bag)
    data = bytearray(path.read_bytes())
    pos = 8                                       # after the magic: records (opcode u8, length u64)
    while data[pos] != 0x06:                      # 0x06: Chunk
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    body = pos + 9                                # start, end, uncompressed size (u64), crc (u32)
    compression = struct.unpack_from("<I", data, body + 28)[0]
    first = body + 32 + compression + 8           # after the compression name and the records' length
    data[first + 1:first + 9] = b"\xff" * 8
    path.write_bytes(bytes(data))


def _unknown_type(bag: Path) -> None:
    """A bag whose /extra topic has a type no message package defines (definition left out)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_types_from_msg

    from online_em_slam.bag.bagio import jazzy_typestore

    ts = jazzy_typestore()
    ts.register(get_types_from_msg("float64 value\n", "nosuch_msgs/msg/Thing"))
    messages = _messages(ts, BASE_TOPICS)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        extra = writer.add_connection("/extra", "nosuch_msgs/msg/Thing", typestore=ts, msgdef="", rihs01="RIHS01_" + "0" * 64)
        for ns, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], ns, ts.serialize_cdr(msg, msgtype))
        thing = ts.types["nosuch_msgs/msg/Thing"](value=1.0)
        writer.write(extra, T0_NS, ts.serialize_cdr(thing, "nosuch_msgs/msg/Thing"))


def _two_types_one_topic(bag: Path) -> None:
    """/control recorded twice: as TwistStamped and as std_msgs/String (two connections)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from online_em_slam.bag.bagio import jazzy_typestore

    ts = jazzy_typestore()
    messages = _messages(ts, BASE_TOPICS)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        other = writer.add_connection("/control", "std_msgs/msg/String", typestore=ts)
        for ns, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], ns, ts.serialize_cdr(msg, msgtype))
        writer.write(other, T0_NS + 1, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="x"),
                                                         "std_msgs/msg/String"))


def _params(directory: Path, text: str | bytes) -> Path:
    path = directory / "params.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


# name -> what is wrong (the table's "case" column)
CASES = {
    "missing": "the bag path does not exist",
    "plain_file": "a plain text file, not a bag",
    "empty_dir": "an empty directory",
    "truncated_mcap": "mcap cut at a third",
    "corrupt_chunk": "mcap chunk, a record length 2**64-1",
    "garbage_metadata": "metadata.yaml not YAML",
    "foreign_metadata": "metadata.yaml valid YAML, not rosbag2",
    "missing_storage_file": "metadata.yaml, storage file deleted",
    "truncated_sqlite": "sqlite3 bag cut at a third",
    "garbage_sqlite": "a .db3 of random bytes",
    "wrong_type_control": "/control as std_msgs/String",
    "wrong_type_observations": "/landmark_observations as std_msgs/String",
    "wrong_type_odom": "/odom as std_msgs/String",
    "two_types_one_topic": "/control both TwistStamped and String",
    "unknown_type": "an extra topic of an unknown type, no definition",
    "no_motion": "no motion topic (/control, /odom)",
    "no_observations": "no /landmark_observations topic",
    "empty_bag": "a bag with no topics",
    "params_not_yaml": "params file not YAML",
    "params_binary": "params file of binary bytes",
    "params_directory": "params path is a directory",
    "params_bad_value": "params value of the wrong type",
}


def make_case(name: str, directory: Path) -> tuple[Path, Path]:
    """Write case ``name`` under ``directory``: (bag, params)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    bag, params = directory / name, CAR_PARK_PARAMS
    if name == "missing":
        pass
    elif name == "plain_file":
        bag.write_text("hello\n")
    elif name == "empty_dir":
        bag.mkdir()
    elif name in ("truncated_mcap", "corrupt_chunk", "garbage_metadata", "foreign_metadata",
                  "missing_storage_file"):
        write_base(bag)
        if name == "truncated_mcap":
            _truncate(bag, 1 / 3)
        elif name == "corrupt_chunk":
            _corrupt_chunk(bag)
        elif name == "garbage_metadata":
            (bag / "metadata.yaml").write_text("garbage: {{{\n")
        elif name == "foreign_metadata":
            (bag / "metadata.yaml").write_text("name: not a bag\nitems: [1, 2]\n")
        else:
            _storage_file(bag).unlink()
    elif name == "truncated_sqlite":
        write_base(bag, storage="sqlite3")
        _truncate(bag, 1 / 3)
    elif name == "garbage_sqlite":
        write_base(bag, storage="sqlite3")
        _storage_file(bag).write_bytes(np.random.default_rng(1).bytes(20000))
    elif name.startswith("wrong_type_"):
        topic = {"control": "/control", "observations": "/landmark_observations", "odom": "/odom"}[
            name[len("wrong_type_"):]]
        write_base(bag, wrong={topic: True})
    elif name == "two_types_one_topic":
        _two_types_one_topic(bag)
    elif name == "unknown_type":
        _unknown_type(bag)
    elif name == "no_motion":
        write_base(bag, topics=("/landmark_observations",))
    elif name == "no_observations":
        write_base(bag, topics=("/control", "/odom"))
    elif name == "empty_bag":
        write_base(bag, topics=())
    elif name.startswith("params_"):
        bag = write_base(directory / "good")
        params = {"params_not_yaml": lambda: _params(directory, "x: [\n"),
                  "params_binary": lambda: _params(directory, bytes(range(256)) * 4),
                  "params_directory": lambda: directory / "params_dir",
                  "params_bad_value": lambda: _params(directory, "/**:\n  ros__parameters:\n"
                                                                 "    filter.num_particles: many\n")}[name]()
        if name == "params_directory":
            params.mkdir()
    else:
        raise KeyError(name)
    return bag, params


__all__ = ["CASES", "make_case", "write_base", "CAR_PARK_PARAMS"]
