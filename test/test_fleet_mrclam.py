"""The MRCLAM fleet bag (``online-em-slam-convert mrclam --all-robots``) and ``online-em-slam run --fleet``:
on the small synthetic .dat files of test_mrclam.py, and on Dataset 1 when present."""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from online_em_slam.datasets.mrclam import load_mrclam
from online_em_slam.datasets.mrclam.fleet_convert import fleet_report_lines, load_fleet, write_fleet_bag
from online_em_slam.messages.cloud import decode_message

from test_mrclam import EXPECTED_COUNTS, REAL_DATASET1, _cli, _read, _write_dataset


@pytest.fixture(scope="module")
def d1_two_robots(tmp_path_factory):
    """Dataset 1's robots 1 and 2, first 60 s, as one fleet bag (written once for the module)."""
    if not REAL_DATASET1.is_file():
        pytest.skip(f"{REAL_DATASET1} not present")
    bag = tmp_path_factory.mktemp("d1_two_robots") / "bag"
    write_fleet_bag(load_fleet(REAL_DATASET1, 60.0, robots=(1, 2)), bag, progress=False)
    return bag

PARAMS = Path(__file__).resolve().parents[1] / "config" / "mrclam.yaml"


@pytest.fixture()
def two_robots(tmp_path):
    directory = _write_dataset(tmp_path / "MRCLAM_Dataset1", robot=1)
    return _write_dataset(directory, robot=2)


def test_fleet_bag_namespaces_every_robot_and_writes_the_survey_once(two_robots, tmp_path):
    runs = load_fleet(two_robots, robots=(1, 2))
    out = tmp_path / "bag"
    counts = write_fleet_bag(runs, out, progress=False)
    expected = {"/ground_truth/landmarks": 1}
    for robot in (1, 2):
        expected.update({f"/robot{robot}{t}": n for t, n in EXPECTED_COUNTS.items() if t != "/ground_truth/landmarks"})
    assert counts == expected
    messages = _read(out)
    assert Counter(t for t, _, _ in messages) == expected
    stamps = np.array([s for _, s, _ in messages])
    assert np.all(np.diff(stamps) >= -1e-6)                       # one stream, merged in stamp order
    # the same clouds under each namespace as the single-robot bag has them
    single = tmp_path / "single"
    from online_em_slam.datasets.mrclam.convert import write_mrclam_bag
    write_mrclam_bag(load_mrclam(two_robots, 2), single, progress=False)
    ids = [list(decode_message(m)["id"]) for _, _, m in _read(out, ["/robot2/landmark_observations"])]
    assert ids == [list(decode_message(m)["id"]) for _, _, m in _read(single, ["/landmark_observations"])]
    lines = fleet_report_lines(runs)
    assert lines[-1].startswith("robot-to-robot barcode reads ignored")
    assert "robot 1 1, robot 2 1 (total 2)" in lines[-1]


def test_cli_all_robots_errors(two_robots, tmp_path, capsys):
    code, _, err = _cli(["mrclam", str(tmp_path / "b"), "--data-dir", str(two_robots), "--all-robots",
                         "--robot", "1"], capsys)
    assert code == 1 and "exclude each other" in err and err.count("\n") == 1
    code, _, err = _cli(["mrclam", str(tmp_path / "b"), "--data-dir", str(two_robots), "--all-robots"], capsys)
    assert code == 1 and "Robot3_" in err and err.count("\n") == 1          # all five robots' files are needed


def test_run_fleet_on_two_synthetic_robots(two_robots, tmp_path, capsys):
    from online_em_slam.offline.cli import main
    bag = tmp_path / "bag"
    write_fleet_bag(load_fleet(two_robots, robots=(1, 2)), bag, progress=False)
    out = tmp_path / "out"
    assert main(["run", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(out), "--seed", "0",
                 "--particles", "20", "--no-plot"]) == 0
    text = capsys.readouterr().out
    assert "online_em_fleet (2 robots)" in text and "robot2 trajectory RMSE" in text
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["robots_in_fleet"] == ["robot1", "robot2"] and set(metrics["robots"]) == {"robot1", "robot2"}
    for robot in ("robot1", "robot2"):
        rows = np.genfromtxt(out / robot / "trajectory.csv", delimiter=",", names=True)
        assert rows.size >= 1
        assert metrics["robots"][robot]["initial_pose"]["source"].startswith("/ground_truth/pose")
    assert (out / "landmarks.csv").read_text().startswith("id,x,y")
    assert main(["run", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(out),
                 "--initial-pose", "1,2,3"]) == 1
    assert "--initial-pose must be auto or ground_truth" in capsys.readouterr().err


def test_run_fleet_reports_a_robots_inputs_that_fail_inside_the_fleet(two_robots, tmp_path, capsys, monkeypatch):
    """As a single robot's run: counted per robot, the first messages kept, a warning on stderr."""
    from online_em_slam.core import FleetSlam
    from online_em_slam.offline.cli import main
    bag = tmp_path / "bag"
    write_fleet_bag(load_fleet(two_robots, robots=(1, 2)), bag, progress=False)
    original = FleetSlam.add_observations

    def robot_two_fails(self, robot, stamp, observations):
        if robot == 1:
            raise RuntimeError("injected")
        return original(self, robot, stamp, observations)
    monkeypatch.setattr(FleetSlam, "add_observations", robot_two_fails)
    out = tmp_path / "out"
    assert main(["run", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(out), "--seed", "0",
                 "--particles", "20", "--no-plot"]) == 0
    robots = json.loads((out / "metrics.json").read_text())["robots"]
    failed = robots["robot2"]["runner_skipped"]["internal_error"]
    assert failed > 0 and "internal_error" not in robots["robot1"]["runner_skipped"]
    assert "RuntimeError('injected')" in robots["robot2"]["input_failures"][0]
    err = capsys.readouterr().err
    assert f"warning: {failed} input(s) failed inside the fleet (robot robot2)" in err and "robot1" not in err


def test_run_fleet_refuses_a_single_robot_bag(two_robots, tmp_path, capsys):
    from online_em_slam.datasets.mrclam.convert import write_mrclam_bag
    from online_em_slam.offline.cli import main
    bag = tmp_path / "single"
    write_mrclam_bag(load_mrclam(two_robots, 1), bag, progress=False)
    assert main(["run", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(tmp_path / "o")]) == 1
    assert "not a fleet bag" in capsys.readouterr().err


@pytest.mark.skipif(not REAL_DATASET1.is_file(), reason=f"{REAL_DATASET1} not present")
def test_real_dataset1_all_robots_first_60_s(tmp_path, capsys):
    out = tmp_path / "d1"
    code, text, err = _cli(["mrclam", str(out), "--data-dir", str(REAL_DATASET1), "--all-robots",
                            "--seconds", "60", "--no-progress"], capsys)
    assert code == 0, err
    from online_em_slam.bag.bagio import bag_topics
    counts = {t: n for t, (_, n) in bag_topics(out).items()}
    assert counts["/ground_truth/landmarks"] == 1
    for robot in range(1, 6):
        assert counts[f"/robot{robot}/control"] == counts[f"/robot{robot}/odom"] == 3000
        assert counts[f"/robot{robot}/ground_truth/pose"] == 600
    assert counts["/robot1/landmark_observations"] == 80          # as the single-robot bag of robot 1
    assert ("robot-to-robot barcode reads ignored (dropped, not landmarks): robot 1 83, robot 2 53, "
            "robot 3 103, robot 4 55, robot 5 35 (total 329)") in text


def test_real_dataset1_two_robots_run_fleet_60_s(d1_two_robots, tmp_path, capsys):
    from online_em_slam.offline.cli import main
    bag = d1_two_robots
    out = tmp_path / "out"
    assert main(["run", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(out), "--seed", "0",
                 "--particles", "50", "--no-plot"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    lm = metrics["landmarks"]
    assert lm["n_true"] == 15 and lm["n_matched"] >= 10 and lm["shape_error"] < 0.5
    for robot in ("robot1", "robot2"):
        assert metrics["robots"][robot]["trajectory"]["rmse"] < 0.5
        assert metrics["robots"][robot]["n_observation_messages"] > 50
    assert metrics["n_confirmed_landmarks"] == metrics["landmarks"]["n_matched"] + metrics["landmarks"]["n_spurious"]


class _Broken:
    """An observation payload that passes the input path and fails inside the estimator."""

    def __len__(self) -> int:
        return 1


def _fleet_inputs():
    """Two robots on unicycle circles, each reading three known landmarks every 0.5 s."""
    from online_em_slam.core import Observations
    landmarks = np.array([[3.0, 1.0], [-2.0, 4.0], [1.0, -3.0]])
    events = []
    for robot, start in enumerate(((0.0, 0.0, 0.0), (1.0, -1.0, 1.0))):
        pose = np.array(start)
        for k in range(101):
            t = 1.0 + 0.1 * k
            events.append((t, robot, 2, (0.5, 0.2)))             # CONTROL
            if k % 5 == 0:
                d = landmarks - pose[:2]
                events.append((t, robot, 1, Observations(np.hypot(d[:, 0], d[:, 1]),
                                                         np.arctan2(d[:, 1], d[:, 0]) - pose[2], np.arange(3))))
            pose = pose + 0.1 * np.array([0.5 * np.cos(pose[2]), 0.5 * np.sin(pose[2]), 0.2])
    return sorted(events, key=lambda e: (e[0], e[1], e[2] != 2)), [(0.0, 0.0, 0.0), (1.0, -1.0, 1.0)]


def test_fleet_pipeline_undoes_a_failing_input_on_the_whole_fleet():
    """A robot's input that raises is dropped (internal_error, that robot) and the fleet, map and the
    other robot included, is as if it had been an empty cloud (the same place in the input order)."""
    from online_em_slam.core import FleetSlam, Observations, SlamConfig
    from online_em_slam.pipeline.fleet import FleetPipeline
    config = SlamConfig.from_dict({"motion": {"model": "unicycle"}, "filter": {"num_particles": 20, "seed": 3}})
    events, starts = _fleet_inputs()
    results = []
    for broken in (False, True):
        fleet = FleetSlam(config, starts)
        pipeline = FleetPipeline(fleet, "control", 1.0, 1.0)
        for i, (t, robot, kind, payload) in enumerate(events):
            pipeline.push(robot, kind, t, payload, t)
            if i == len(events) // 2:
                empty = Observations(np.zeros(0), np.zeros(0), np.zeros(0, dtype=int))
                pipeline.push(1, 1, t + 1e-3, _Broken() if broken else empty, t)
        pipeline.flush()
        results.append((fleet, pipeline))
    (clean, _), (fleet, pipeline) = results
    assert pipeline.drops(1)["internal_error"] == 1 and not pipeline.drops(0)["internal_error"]
    # the restored copy's arrays may sit at other addresses: sums can differ in the last bits
    np.testing.assert_allclose(fleet.landmarks().positions, clean.landmarks().positions, rtol=0, atol=1e-9)
    for robot in (0, 1):
        np.testing.assert_allclose(fleet.pose(robot).mean, clean.pose(robot).mean, rtol=0, atol=1e-9)
    assert len(clean.landmarks()) == 3


def test_fleet_batch_puts_the_robots_problems_end_to_end():
    from online_em_slam.offline.batch import InputsProblem
    from online_em_slam.offline.fleet_batch import end_to_end

    def problem(n_poses, obs_pose, ids):
        return InputsProblem(np.arange(n_poses, dtype=float), np.ones((n_poses - 1, 3)),
                             np.tile(np.eye(3), (n_poses - 1, 1, 1)), np.asarray(obs_pose), np.asarray(ids),
                             np.ones((len(ids), 2)), np.tile(np.eye(2), (len(ids), 1, 1)), Counter(a=1))

    joint = end_to_end([problem(3, [1, 2], [6, 7]), problem(4, [1, 3, 3], [7, 8, 9])])
    assert joint.chain_starts == (0, 3) and len(joint.stamps) == 7
    assert joint.increments.shape == (6, 3) and np.all(joint.increments[2] == 0)     # into robot 2's start: unused
    assert joint.obs_pose.tolist() == [1, 2, 4, 6, 6] and joint.obs_id.tolist() == [6, 7, 7, 8, 9]
    assert joint.skipped == Counter(a=2)


def test_real_dataset1_two_robots_fleet_batch_60_s(d1_two_robots, tmp_path, capsys):
    pytest.importorskip("gtsam")
    from online_em_slam.offline.fleet_batch import main
    bag = d1_two_robots
    out = tmp_path / "batch"
    assert main([str(bag), "--params", str(PARAMS), "--output", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["landmarks"]["n_matched"] >= 10 and metrics["landmarks"]["shape_error"] < 0.5
    for robot in ("robot1", "robot2"):
        assert metrics["robots"][robot]["trajectory"]["rmse"] < 0.5
        assert (out / robot / "trajectory.csv").is_file()


def test_real_dataset1_two_robots_fleet_batch_with_robot_reads_60_s(d1_two_robots, tmp_path, capsys):
    """The MRCLAM front end of the fleet batch: every read between robots 1 and 2 in the bag's 60 s
    gets both poses (none left without a variable) and the robots stay on their ground truth."""
    pytest.importorskip("gtsam")
    from online_em_slam.datasets.mrclam.fleet_batch import main
    out = tmp_path / "batch"
    assert main([str(d1_two_robots), "--params", str(PARAMS), "--output", str(out),
                 "--robot-reads", str(REAL_DATASET1)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    reads = metrics["robot_reads"]
    assert reads["in_the_bag"] > 0 and reads["used"] + sum(reads["left_out"].values()) == reads["in_the_bag"]
    assert "no_pose_variable" not in reads["left_out"] and reads["not_in_the_bag"]["robot_not_in_fleet"] > 0
    assert metrics["landmarks"]["n_matched"] >= 10
    for robot in ("robot1", "robot2"):
        assert metrics["robots"][robot]["trajectory"]["rmse"] < 0.5
    assert "robot-to-robot reads" in capsys.readouterr().out


def test_real_dataset1_two_robots_compare_fleet_60_s(d1_two_robots, tmp_path, capsys):
    """compare --fleet: the fleet run and the five-robot batch with the files' and the learned noise."""
    pytest.importorskip("gtsam")
    from online_em_slam.offline.cli import main
    bag = d1_two_robots
    out = tmp_path / "compare"
    assert main(["compare", str(bag), "--fleet", "--params", str(PARAMS), "--output", str(out), "--seed", "0",
                 "--particles", "50", "--no-plot"]) == 0
    rows = json.loads((out / "comparison.json").read_text())["methods"]
    assert [r["method"] for r in rows] == ["online_em_fleet", "batch_fleet_params", "batch_fleet_learned"]
    for row in rows:
        assert row["n_true"] == 15 and row["within_gate"] >= 10 and row["shape"] < 0.5
        assert set(row["trajectory_rmse"]) == {"robot1", "robot2"}
    assert (out / "batch_fleet_learned" / "metrics.json").is_file()
    assert "learned" in json.loads((out / "batch_fleet_learned" / "metrics.json").read_text())["noise"]
    assert "| online_em_fleet |" in (out / "comparison.md").read_text()
