"""Bad bags and parameter files (reliability, item 6): ``online-em-slam run`` and
``online-em-slam-replay`` print one line ``<tool>: error: <file>: <what is wrong>`` and exit
1, without a traceback; the replay publishes no topic under a name the node reads with
another type.  The corpus is test/bad_bag_corpus.py; docs/RESULTS.md ("Reliability") has
the table of before and after."""
from __future__ import annotations

import json

import numpy as np
import pytest

from bad_bag_corpus import CASES, make_case
from ros_domain import claim

# case -> what the error line says (after the file name), for run and for the replay
# (None: the case is a parameter file, which the replay does not read).
EXPECTED = {
    "missing": ("does not exist", "does not exist"),
    "plain_file": ("not a bag: a plain file", "not a bag: a plain file"),
    "empty_dir": ("not a bag: the directory has no metadata.yaml",) * 2,
    "truncated_mcap": ("cannot read the bag: ", "cannot read the bag: "),
    "corrupt_chunk": ("cannot read the bag: OverflowError", "cannot read the bag: OverflowError"),
    "garbage_metadata": ("cannot read the bag: ", "cannot read the bag: "),
    "foreign_metadata": ("cannot read the bag: ", "cannot read the bag: "),
    "missing_storage_file": ("cannot read the bag: ", "cannot read the bag: "),
    "truncated_sqlite": ("cannot read the bag: ", "cannot read the bag: "),
    "garbage_sqlite": ("cannot read the bag: ", "cannot read the bag: "),
    "wrong_type_control": ("/control is std_msgs/msg/String, expected geometry_msgs/msg/TwistStamped",) * 2,
    "wrong_type_observations": ("/landmark_observations is std_msgs/msg/String, expected "
                                "sensor_msgs/msg/PointCloud2",) * 2,
    "wrong_type_odom": ("/odom is std_msgs/msg/String, expected nav_msgs/msg/Odometry",) * 2,
    "two_types_one_topic": ("/control is recorded with 2 types",) * 2,
    "unknown_type": ("cannot read the bag: ", None),      # the replay skips the topic: see below
    "no_motion": ("no motion input: no messages on /control", "no motion input for the node"),
    "no_observations": ("no observations: no messages on /landmark_observations",
                        "no observations for the node"),
    "empty_bag": ("the bag holds no messages", "the bag holds no messages"),
    "params_not_yaml": ("not a YAML parameter file", None),
    "params_binary": ("not a YAML parameter file", None),
    "params_directory": ("cannot read the parameter file: Is a directory", None),
    "params_bad_value": ("filter.num_particles: expected an integer, got 'many'", None),
}


def test_every_case_has_an_expectation():
    assert set(EXPECTED) == set(CASES)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad_files")
    return {name: make_case(name, root / name) for name in CASES}


def _one_error_line(err: str, tool: str, path, what: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith(f"{tool}: error: {path}: "), lines[0]
    assert what in lines[0], lines[0]


@pytest.mark.parametrize("name", list(CASES))
def test_run_on_a_bad_file_says_one_line_and_exits_1(corpus, tmp_path, capsys, name):
    from online_em_slam.offline import cli

    bag, params = corpus[name]
    code = cli.main(["run", str(bag), "--params", str(params), "--output", str(tmp_path / "out"), "--no-plot"])
    _one_error_line(capsys.readouterr().err, "online-em-slam", params if name.startswith("params_") else bag,
                    EXPECTED[name][0])
    assert code == 1


REPLAY_REFUSES = [name for name in CASES if EXPECTED[name][1] is not None and name != "corrupt_chunk"]


@pytest.mark.parametrize("name", REPLAY_REFUSES)
def test_replay_refuses_a_bad_bag_before_publishing(corpus, capsys, monkeypatch, name):
    """Refused before rclpy starts: no node, nothing published."""
    from online_em_slam.bag import replay

    def no_ros(*args, **kwargs):
        raise AssertionError("the replay started ROS on a bag it must refuse")

    monkeypatch.setattr("rclpy.init", no_ros)
    code = replay.main([str(corpus[name][0]), "--rate", "0"])
    _one_error_line(capsys.readouterr().err, "online-em-slam-replay", corpus[name][0], EXPECTED[name][1])
    assert code == 1


@pytest.fixture
def ros_isolated(monkeypatch):
    """The replay's node in this process: no discovery beyond it, a domain of its own."""
    pytest.importorskip("rclpy")
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(claim()))


def _summary(out: str) -> dict:
    return json.loads(out.strip().splitlines()[-1].replace("NaN", "null"))


def test_replay_of_a_bag_corrupt_inside_a_chunk_ends_with_one_line(corpus, capsys, ros_isolated):
    """The chunk's record length is only read while playing: one line, exit 1, the summary kept."""
    bag = corpus["corrupt_chunk"][0]
    from online_em_slam.bag import replay

    code = replay.main([str(bag), "--rate", "0", "--quiet", "--ack-timeout", "1"])
    captured = capsys.readouterr()
    _one_error_line(captured.err, "online-em-slam-replay", bag, EXPECTED["corrupt_chunk"][1])
    assert code == 1 and _summary(captured.out)["total"] == 0


def test_replay_skips_an_unknown_type_with_one_warning_and_counts_it(corpus, capsys, ros_isolated):
    """A topic no message package defines is not one the node reads: played without it, one
    warning naming the bag, the topic counted under skipped_topics (exit 0, as for a /tf_static
    whose tf2_msgs is not installed)."""
    bag = corpus["unknown_type"][0]
    from online_em_slam.bag import replay

    code = replay.main([str(bag), "--rate", "0", "--ack-timeout", "1"])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert lines == [f"online-em-slam-replay: warning: {bag}: skipping /extra: nosuch_msgs/msg/Thing "
                     "is not importable"]
    summary = _summary(captured.out)
    assert code == 0 and "/extra" in summary["skipped_topics"] and summary["published"]["/control"] > 0


def test_replay_no_input_check_plays_a_bag_without_observations(corpus, capsys, ros_isolated):
    from bad_bag_corpus import N_CONTROL, N_ODOM
    from online_em_slam.bag import replay

    bag = corpus["no_observations"][0]
    code = replay.main([str(bag), "--rate", "0", "--quiet", "--no-input-check", "--ack-timeout", "1"])
    summary = _summary(capsys.readouterr().out)
    assert code == 0 and summary["published"] == {"/control": N_CONTROL, "/odom": N_ODOM}


def test_replay_checks_types_under_the_published_name(corpus, capsys, monkeypatch):
    """--remap /control:=/odom would publish TwistStamped on the node's odometry topic: refused."""
    from online_em_slam.bag import replay

    monkeypatch.setattr("rclpy.init", lambda *a, **k: pytest.fail("started ROS"))
    bag = corpus["params_not_yaml"][0]          # the good bag of the parameter cases
    code = replay.main([str(bag), "--rate", "0", "--remap", "/control:=/odom", "--exclude", "/odom"])
    _one_error_line(capsys.readouterr().err, "online-em-slam-replay", bag,
                    "/odom is geometry_msgs/msg/TwistStamped, expected nav_msgs/msg/Odometry")
    assert code == 1


def test_replay_plays_a_bag_whose_wrongly_typed_topic_is_excluded(corpus, capsys, ros_isolated):
    from bad_bag_corpus import N_CLOUDS, N_CONTROL
    from online_em_slam.bag import replay

    code = replay.main([str(corpus["wrong_type_odom"][0]), "--rate", "0", "--quiet", "--exclude", "/odom",
                        "--ack-timeout", "1"])
    summary = _summary(capsys.readouterr().out)
    assert code == 0 and summary["published"] == {"/control": N_CONTROL, "/landmark_observations": N_CLOUDS}


def test_parameter_error_names_the_file_that_set_it(corpus, tmp_path, capsys):
    """Of two --params files, the one whose value is refused is named."""
    from online_em_slam.offline import cli

    bag, bad = corpus["params_bad_value"]
    good = tmp_path / "good.yaml"
    good.write_text("/**:\n  ros__parameters:\n    filter.num_particles: 10\n")
    code = cli.main(["run", str(bag), "--params", str(bad), "--params", str(good), "--output", str(tmp_path / "o")])
    assert code == 0, capsys.readouterr().err                 # the later file's value wins
    capsys.readouterr()
    code = cli.main(["run", str(bag), "--params", str(good), "--params", str(bad), "--output", str(tmp_path / "o")])
    _one_error_line(capsys.readouterr().err, "online-em-slam", bad, "expected an integer")
    assert code == 1


def test_tum_files_of_an_empty_trajectory(tmp_path):
    """A run whose observations all came before the first motion input has no pose: the TUM
    files are written empty (before: 'cannot reshape array of size 0')."""
    from online_em_slam.offline.tum import write_run_tum

    written = write_run_tum(tmp_path, np.zeros((0, 4)), (3.78, 0.5))
    assert [p.read_text() for p in written] == ["# timestamp x y z qx qy qz qw\n"] * 2
