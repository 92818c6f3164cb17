"""Issue 23 item 7: the RViz view follows the node's namespace (online_em_slam/ros/rviz_config.py)."""
from pathlib import Path

import pytest
import yaml

from online_em_slam.ros import rviz_config
from online_em_slam.ros.rviz_config import namespaced_config, normalise_namespace

RVIZ = Path(__file__).resolve().parent.parent / "rviz" / "online_em_slam.rviz"
NODE_TOPICS = {"/online_em_slam/pose", "/online_em_slam/path", "/online_em_slam/particles",
               "/online_em_slam/landmarks", "/online_em_slam/landmark_markers", "/landmark_observations",
               "/initialpose"}


def topics(text: str) -> set[str]:
    found = set()

    def walk(item):
        if isinstance(item, dict):
            if isinstance(item.get("Topic"), dict):
                found.add(item["Topic"]["Value"])
            for value in item.values():
                walk(value)
        elif isinstance(item, list):
            for value in item:
                walk(value)
    walk(yaml.safe_load(text))
    return found


def test_the_robot_topics_move_into_the_namespace_and_the_shared_ones_stay():
    text = RVIZ.read_text()
    assert NODE_TOPICS <= topics(text)
    moved = namespaced_config(text, "robot1")
    robot = {t for t in topics(text) if not rviz_config.is_shared(t)}
    assert robot == NODE_TOPICS | {"/scan"}
    assert topics(moved) == {f"/robot1{t}" for t in robot} | {t for t in topics(text) if rviz_config.is_shared(t)}
    assert {"/ground_truth/landmarks", "/ground_truth/position", "/clicked_point"} <= topics(moved)
    config = yaml.safe_load(moved)
    assert config["Visualization Manager"]["Global Options"]["Fixed Frame"] == "map"
    # Everything else is the same view.
    assert len(config["Visualization Manager"]["Displays"]) == len(yaml.safe_load(text)["Visualization Manager"]
                                                                   ["Displays"])


def test_fixed_frame_and_no_namespace():
    text = RVIZ.read_text()
    assert topics(namespaced_config(text, "")) == topics(text)
    framed = yaml.safe_load(namespaced_config(text, "/robot2/", "robot2/map"))
    assert framed["Visualization Manager"]["Global Options"]["Fixed Frame"] == "robot2/map"
    assert "/robot2/online_em_slam/pose" in topics(yaml.safe_dump(framed))
    assert rviz_config.write_namespaced_config(str(RVIZ), "") == str(RVIZ)      # nothing to change: the file


def test_written_config_and_command_line(tmp_path, capsys):
    path = Path(rviz_config.write_namespaced_config(str(RVIZ), "fleet/robot1"))
    try:
        assert "/fleet/robot1/online_em_slam/landmarks" in topics(path.read_text())
    finally:
        path.unlink()
    assert rviz_config.main(["--namespace", "robot1", str(RVIZ)]) == 0
    assert "/robot1/initialpose" in topics(capsys.readouterr().out)
    assert rviz_config.main(["--namespace", "1robot", str(RVIZ)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rviz_config: error: namespace '1robot'") and err.count("\n") == 1
    (tmp_path / "bad.rviz").write_text("just: text\n")
    assert rviz_config.main([str(tmp_path / "bad.rviz")]) == 1
    assert "not an RViz configuration" in capsys.readouterr().err


@pytest.mark.parametrize("namespace, expected", [("robot1", "/robot1"), ("/a/b/", "/a/b"), ("", ""), ("/", "")])
def test_namespaces_are_normalised(namespace, expected):
    assert normalise_namespace(namespace) == expected


def test_the_config_of_a_namespace_names_the_topics_of_a_node_in_it(ros):
    """A node in robot1 with its TF tree in the namespace (multi_robot.launch.py): the
    generated config's robot topics are the node's own, and map -> odom goes to /robot1/tf."""
    from online_em_slam.ros.node import OnlineEmSlamNode
    node = ros.node = OnlineEmSlamNode(context=ros.context, namespace="robot1",
                                       cli_args=["--ros-args", "-r", "/tf:=tf", "-r", "/tf_static:=tf_static"])
    ros.executor.add_node(node)
    names = {p.topic_name for p in node.publishers} | {s.topic_name for s in node.subscriptions}
    shown = topics(namespaced_config(RVIZ.read_text(), "robot1"))
    assert {t for t in shown if t.startswith("/robot1/")} - {"/robot1/scan"} <= names
    assert {f"/robot1{t}" for t in NODE_TOPICS} <= names
    if node.outputs.transform.kind.startswith("tf2"):
        assert "/robot1/tf" in names and "/tf" not in names


def test_a_fleet_config_shows_every_robot_and_the_map_once():
    """Issue 25 item 5: one RViz for a fleet node: each robot's pose, path, particles, observations
    and "2D Pose Estimate" tool under its namespace, the one map and the shared topics once."""
    text = RVIZ.read_text()
    fleet = rviz_config.fleet_config(text, ["robot1", "robot2"])
    shown = topics(fleet)
    for robot in ("robot1", "robot2"):
        assert {f"/{robot}/pose", f"/{robot}/path", f"/{robot}/particles", f"/{robot}/landmark_observations",
                f"/{robot}/initialpose"} <= shown
    assert {"/online_em_slam/landmarks", "/online_em_slam/landmark_markers", "/ground_truth/landmarks"} <= shown
    assert not {"/online_em_slam/pose", "/initialpose", "/landmark_observations"} & shown
    displays = yaml.safe_load(fleet)["Visualization Manager"]["Displays"]
    names = [d["Name"] for d in displays]
    assert len(names) == len(set(names)) and names.count("Landmarks (estimate)") == 1
    under = topics(rviz_config.fleet_config(text, ["robot1"], namespace="site"))
    assert {"/site/robot1/pose", "/site/online_em_slam/landmarks", "/ground_truth/landmarks"} <= under
    with pytest.raises(ValueError):
        rviz_config.fleet_config(text, [])
