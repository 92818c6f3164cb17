"""The RViz view for a node in a namespace: the installed config with the robot's topics moved under it.

``rviz/online_em_slam.rviz`` names the topics of a node without a namespace
(``/online_em_slam/pose``, ``/landmark_observations``, the "2D Pose Estimate" tool's
``/initialpose``).  Under ``namespace:=robot1`` the node's topics are
``/robot1/online_em_slam/pose``, ``/robot1/landmark_observations``,
``/robot1/initialpose``: :func:`namespaced_config` rewrites every topic of the config
but the shared ones (:data:`SHARED_TOPICS`: ground truth, /tf, /clock, clicked points)
into the namespace, and optionally sets the fixed frame.  The launch file does this at
launch (``rviz:=true namespace:=robot1``); by hand::

    python -m online_em_slam.ros.rviz_config --namespace robot1 > robot1.rviz
    rviz2 -d robot1.rviz --ros-args -r __ns:=/robot1 -r /tf:=tf -r /tf_static:=tf_static

(the remaps only when each robot has its TF tree in its namespace, as in
``launch/multi_robot.launch.py``).  For one node of a fleet (``robots`` parameter),
:func:`fleet_config` shows every robot's pose, path, particles and observations and the
one map (``--robots robot1 robot2``; ``launch/fleet.launch.py``).  No rclpy import:
usable from a launch file.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile

import yaml

# Topics that stay where they are under any namespace (prefixes end with "/").
SHARED_TOPICS = ("/ground_truth/", "/tf", "/tf_static", "/clock", "/clicked_point", "/parameter_events", "/rosout")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def normalise_namespace(namespace: str) -> str:
    """``"robot1"``, ``"/robot1/"`` -> ``"/robot1"``; ``""`` or ``"/"`` -> ``""``; ValueError if not a ROS name."""
    parts = [p for p in namespace.strip().split("/") if p]
    for part in parts:
        if not _NAME.fullmatch(part):
            raise ValueError(f"namespace {namespace!r}: '{part}' is not a valid ROS name "
                             "(letters, digits and '_', not starting with a digit)")
    return "".join(f"/{p}" for p in parts)


def is_shared(topic: str) -> bool:
    return any(topic == t or (t.endswith("/") and topic.startswith(t)) for t in SHARED_TOPICS)


def namespaced_topic(topic: str, namespace: str) -> str:
    """``topic`` of the config under ``namespace`` (normalised); shared and relative topics unchanged."""
    if not namespace or not topic.startswith("/") or is_shared(topic):
        return topic
    return namespace + topic


def _rewrite(item, namespace: str) -> None:
    if isinstance(item, dict):
        topic = item.get("Topic")
        if isinstance(topic, dict) and isinstance(topic.get("Value"), str):
            topic["Value"] = namespaced_topic(topic["Value"], namespace)
        for value in item.values():
            _rewrite(value, namespace)
    elif isinstance(item, list):
        for value in item:
            _rewrite(value, namespace)


def namespaced_config(text: str, namespace: str, fixed_frame: str = "") -> str:
    """The RViz config ``text`` with its robot topics under ``namespace`` and, when given, ``fixed_frame``."""
    ns = normalise_namespace(namespace)
    config = yaml.safe_load(text)
    if not isinstance(config, dict) or "Visualization Manager" not in config:
        raise ValueError("not an RViz configuration (no 'Visualization Manager')")
    _rewrite(config, ns)
    if fixed_frame.strip():
        config["Visualization Manager"].setdefault("Global Options", {})["Fixed Frame"] = fixed_frame.strip()
    return yaml.safe_dump(config, sort_keys=False, default_flow_style=False)


# The single node's per-robot topics and where a fleet node publishes or reads them for robot r.
FLEET_ROBOT_TOPICS = {"/online_em_slam/pose": "pose", "/online_em_slam/path": "path",
                      "/online_em_slam/particles": "particles", "/landmark_observations": "landmark_observations",
                      "/scan": "scan", "/initialpose": "initialpose"}


def fleet_config(text: str, robots, namespace: str = "", fixed_frame: str = "") -> str:
    """The RViz config ``text`` for a fleet node (``robots`` its namespaces, docs/NODE.md "Fleet
    mode"): every display and tool of a robot topic once per robot, named after it and reading
    ``/<robot>/pose`` ... (``<robot>/initialpose`` for the "2D Pose Estimate" tool); the map
    and the shared topics once; the node's ``namespace`` in front of every robot and node topic."""
    robots = [normalise_namespace(r) for r in robots]
    if not robots or not all(robots):
        raise ValueError("fleet_config needs at least one robot namespace")
    config = yaml.safe_load(text)
    if not isinstance(config, dict) or "Visualization Manager" not in config:
        raise ValueError("not an RViz configuration (no 'Visualization Manager')")
    manager = config["Visualization Manager"]
    for key in ("Displays", "Tools"):
        manager[key] = [copy for item in manager.get(key, []) for copy in _per_robot(item, robots)]
    _rewrite(config, normalise_namespace(namespace))
    if fixed_frame.strip():
        manager.setdefault("Global Options", {})["Fixed Frame"] = fixed_frame.strip()
    return yaml.safe_dump(config, sort_keys=False, default_flow_style=False)


def _per_robot(item: dict, robots: list[str]) -> list[dict]:
    """``item`` itself, or one copy per robot when it shows a robot topic."""
    topic = item.get("Topic") if isinstance(item, dict) else None
    value = topic.get("Value") if isinstance(topic, dict) else None
    if value not in FLEET_ROBOT_TOPICS:
        return [item]
    copies = []
    for robot in robots:
        copy = yaml.safe_load(yaml.safe_dump(item))
        copy["Topic"]["Value"] = f"{robot}/{FLEET_ROBOT_TOPICS[value]}"
        if "Name" in copy:
            copy["Name"] = f"{copy['Name']} {robot.lstrip('/')}"
        copies.append(copy)
    return copies


def write_namespaced_config(path: str, namespace: str, fixed_frame: str = "") -> str:
    """``path`` itself when nothing changes, else a generated copy in the temporary directory."""
    if not normalise_namespace(namespace) and not fixed_frame.strip():
        return path
    with open(path, encoding="utf-8") as handle:
        text = namespaced_config(handle.read(), namespace, fixed_frame)
    tag = normalise_namespace(namespace).strip("/").replace("/", "_") or "root"
    fd, out = tempfile.mkstemp(prefix=f"online_em_slam_{tag}_", suffix=".rviz")
    with os.fdopen(fd, "w", encoding="utf-8") as handle:
        handle.write(text)
    return out


def default_config() -> str:
    """The RViz config of the source tree, else the installed one."""
    here = os.path.dirname(os.path.abspath(__file__))
    candidates = [os.path.join(here, "..", "..", "rviz", "online_em_slam.rviz"),
                  os.path.join(sys.prefix, "share", "online_em_slam", "rviz", "online_em_slam.rviz")]
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.insert(1, os.path.join(get_package_share_directory("online_em_slam"), "rviz",
                                          "online_em_slam.rviz"))
    except Exception:  # noqa: BLE001 - not importable, or the package is not in the ament index
        pass
    for candidate in candidates:
        if os.path.isfile(candidate):
            return os.path.normpath(candidate)
    raise FileNotFoundError("rviz/online_em_slam.rviz not found (give the config file)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m online_em_slam.ros.rviz_config",
                                     description="Print the RViz config for a node in a namespace.")
    parser.add_argument("config", nargs="?", default=None, help="RViz config (default: the package's)")
    parser.add_argument("--namespace", default="", help="the node's namespace, e.g. robot1")
    parser.add_argument("--fixed-frame", default="", help="RViz fixed frame (default: the config's)")
    parser.add_argument("--robots", nargs="+", default=None,
                        help="a fleet node's robots (its robots parameter): their displays once each")
    args = parser.parse_args(argv)
    try:
        path = args.config or default_config()
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
        if args.robots:
            sys.stdout.write(fleet_config(text, args.robots, args.namespace, args.fixed_frame))
        else:
            sys.stdout.write(namespaced_config(text, args.namespace, args.fixed_frame))
    except (OSError, ValueError, yaml.YAMLError) as error:
        print(f"rviz_config: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
