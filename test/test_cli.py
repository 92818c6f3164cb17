"""Offline runner (online-em-slam run/compare) on the converted Car Park bag, and param files."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from online_em_slam.offline import cli
from online_em_slam.parameters.yaml_file import ParamFileError, config_from_params, load_params

ROOT = Path(__file__).resolve().parent.parent
CAR_PARK_PARAMS = ROOT / "config" / "car_park.yaml"


@pytest.fixture(scope="module")
def car_park_bag(tmp_path_factory):
    from online_em_slam.datasets.kth.convert import convert
    bag = tmp_path_factory.mktemp("bags") / "car_park"
    convert("car_park", bag, progress=False)
    return bag


def _header(path):
    with open(path, newline="") as handle:
        return next(csv.reader(handle))


def test_run_writes_outputs_and_is_deterministic(car_park_bag, tmp_path):
    out_a, out_b = tmp_path / "a", tmp_path / "b"
    common = [str(car_park_bag), "--params", str(CAR_PARK_PARAMS), "--seed", "3"]
    assert cli.main(["run", *common, "--output", str(out_a)]) == 0
    assert cli.main(["run", *common, "--output", str(out_b), "--no-plot"]) == 0

    assert _header(out_a / "trajectory.csv") == ["t", "x", "y", "yaw"]
    assert _header(out_a / "landmarks.csv") == ["id", "x", "y", "cov_xx", "cov_xy", "cov_yy", "n_obs"]
    assert (out_a / "map.png").stat().st_size > 10_000 and not (out_b / "map.png").exists()
    # same seed -> identical outputs
    assert (out_a / "trajectory.csv").read_text() == (out_b / "trajectory.csv").read_text()
    assert (out_a / "landmarks.csv").read_text() == (out_b / "landmarks.csv").read_text()

    m = json.loads((out_a / "metrics.json").read_text())
    for key in ("method", "seed", "num_particles", "initial_pose", "n_landmarks", "n_confirmed_landmarks",
                "timing", "drops", "landmarks", "trajectory"):
        assert key in m, key
    assert m["method"] == "online_em" and m["seed"] == 3 and m["motion_model"] == "acfr"
    for key in ("n_true", "n_matched", "n_missed", "n_spurious", "rmse", "matches"):
        assert key in m["landmarks"], key
    for key in ("alignment", "rmse", "median", "max", "n_compared"):
        assert key in m["trajectory"], key
    for key in ("mean_step_ms", "p99_step_ms", "real_time_factor", "wall_time_s", "dataset_duration_s"):
        assert key in m["timing"], key
    assert m["trajectory"]["alignment"] == "none"
    assert m["frame"]["same_frame"] is True and not any(m["frame"]["to_truth"])    # auto: the GPS start
    assert m["timing"]["dataset_duration_s"] == pytest.approx(125.05, abs=0.1)
    assert m["landmarks"]["n_true"] == 15
    # sanity of the tuned configuration (loose bounds: the report gives the measured values)
    assert m["landmarks"]["n_matched"] >= 13 and m["landmarks"]["rmse"] < 1.0
    assert m["trajectory"]["median"] < 1.5
    # the replays filtered the past again: that trajectory scored too, and written for evo
    assert m["trajectory_revised"]["rmse"] < 1.5 and (out_a / "trajectory_revised.tum").exists()
    rows = (out_a / "trajectory.csv").read_text().splitlines()
    assert len(rows) - 1 == m["n_observation_messages"]      # one pose per observation message (586)


def test_run_started_outside_the_truth_frame_says_so_and_scores_in_it(car_park_bag, tmp_path, capsys):
    """--initial-pose params ((0, 0, 0): the car park's GPS frame has the car elsewhere) used to
    score 1/15 beacons and 22 m of trajectory error without a word about the frames."""
    out = tmp_path / "params"
    assert cli.main(["run", str(car_park_bag), "--params", str(CAR_PARK_PARAMS), "--seed", "3",
                     "--initial-pose", "params", "--output", str(out), "--no-plot"]) == 0
    printed = capsys.readouterr().out
    assert "after moving the estimate by its start pose" in printed
    assert "note: the estimate's frame is not the ground truth's" in printed
    m = json.loads((out / "metrics.json").read_text())
    assert m["frame"]["same_frame"] is False and m["frame"]["offset_m"] > 5.0
    assert m["frame"]["initial_pose_source"] == "default (0, 0, 0)"
    assert m["landmarks"]["n_matched"] >= 13 and m["landmarks"]["rmse"] < 1.0
    assert m["trajectory"]["median"] < 1.5


def test_run_reports_inputs_that_fail_inside_the_estimator(car_park_bag, tmp_path, capsys, monkeypatch):
    """A scan that raises inside the estimator is dropped with the estimate kept (the node's rule);
    the offline run used to count it in metrics.json alone, so a run could lose most of its scans
    without a word on the terminal.  The failing scans fail as a bug would: each one every time it
    is applied, the others never (the rollback applies those again)."""
    from online_em_slam.core.filter.slam import OnlineEMSlam
    original, seen = OnlineEMSlam.add_observations, {}

    def every_25th_scan_fails(self, stamp, observations):
        if seen.setdefault(stamp, len(seen)) % 25 == 24:
            raise RuntimeError("injected")
        return original(self, stamp, observations)

    monkeypatch.setattr(OnlineEMSlam, "add_observations", every_25th_scan_fails)
    out = tmp_path / "failing"
    assert cli.main(["run", str(car_park_bag), "--params", str(CAR_PARK_PARAMS), "--seed", "3",
                     "--output", str(out), "--no-plot"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    failed = m["runner_skipped"]["internal_error"]
    assert failed == sum(index % 25 == 24 for index in seen.values()) >= 20      # of the 586 scans
    assert "reapply_failed" not in m["runner_skipped"]
    assert len(m["input_failures"]) == 5 and all("RuntimeError('injected')" in f for f in m["input_failures"])
    assert m["input_failures"][0].startswith("observations at ")
    warning = capsys.readouterr().err
    assert f"warning: {failed} input(s) failed inside online_em" in warning and "injected" in warning


def test_compare_writes_table(car_park_bag, tmp_path):
    """Two parameter files merge in order: the second sets the particles, the first's motion model stays."""
    out, fewer = tmp_path / "cmp", tmp_path / "fewer.yaml"
    fewer.write_text("/**:\n  ros__parameters:\n    filter.num_particles: 20\n")
    assert cli.main(["compare", str(car_park_bag), "--params", str(CAR_PARK_PARAMS), "--params", str(fewer),
                     "--output", str(out), "--methods", "online_em", "ekf_slam", "--no-plot"]) == 0
    table = json.loads((out / "comparison.json").read_text())
    assert table["num_particles"] == 20 and table["params"] == f"{CAR_PARK_PARAMS} + {fewer}"
    assert json.loads((out / "online_em" / "metrics.json").read_text())["motion_model"] == "acfr"
    assert [r["method"] for r in table["methods"]] == ["online_em", "ekf_slam"]
    for key in ("beacons_mapped", "spurious", "beacon_rmse_m", "trajectory_rmse_m", "mean_ms_per_step",
                "real_time_factor"):
        assert key in table["methods"][0], key
    text = (out / "comparison.md").read_text()
    assert "| method |" in text and "| ekf_slam |" in text
    assert (out / "ekf_slam" / "metrics.json").exists()


def test_run_reports_errors(tmp_path):
    assert cli.main(["run", str(tmp_path / "missing"), "--params", str(CAR_PARK_PARAMS),
                     "--output", str(tmp_path / "o")]) == 1


def test_param_file_formats(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    motion_source: control\n    motion:\n      model: acfr\n"
        "      wheelbase: 2.83\n    filter.num_particles: 10\n"
        "/**/online_em_slam:\n  ros__parameters:\n    filter:\n      num_particles: 20\n"
        "other_node:\n  ros__parameters:\n    filter.num_particles: 30\n")
    values = load_params(path)
    assert values == {"motion_source": "control", "motion.model": "acfr", "motion.wheelbase": 2.83,
                      "filter.num_particles": 20}
    config, settings = config_from_params(path)
    assert config.motion.model == "acfr" and config.filter.num_particles == 20
    assert settings.motion_source == "control"
    config, _ = config_from_params({"online_em_slam": {"ros__parameters": {"sensor": {"offset_x": 1.5}}}})
    assert config.sensor.offset_x == 1.5
    config, _ = config_from_params({"noise.sigma_range": 0.2}, {"filter.seed": 5})
    assert config.noise.sigma_range == 0.2 and config.filter.seed == 5
    bad = tmp_path / "bad.yaml"
    bad.write_text("other_node:\n  ros__parameters:\n    a: 1\n")
    with pytest.raises(ParamFileError):
        load_params(bad)
    c, s = config_from_params(CAR_PARK_PARAMS)
    assert (c.motion.model, s.motion_source, s.control_angular) == ("acfr", "control", "steering")
    c, s = config_from_params(ROOT / "config" / "victoria_park.yaml")
    assert (c.motion.model, s.motion_source, c.sensor.offset_x) == ("acfr", "control", 3.78)
    # The KTH files set no noise value and no noise family: every one is the default
    # (Student-t), learned online.
    defaults = config_from_params({})[0]
    assert defaults.noise_learning.enabled and defaults.noise.model == "student_t"
    for name in ("car_park", "victoria_park"):
        c, _ = config_from_params(ROOT / "config" / f"{name}.yaml")
        assert c.noise_learning.enabled and c.noise == defaults.noise
        assert (c.motion.sigma_speed, c.sensor.offset_x) == (defaults.motion.sigma_speed, 3.78)
        hand, _ = config_from_params(ROOT / "config" / "hand_tuned" / f"{name}.yaml")
        assert not hand.noise_learning.enabled and hand.noise.model == "mixture"


def test_params_build_importable_without_ros():
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path, target=None):\n"
            "        if name.split('.')[0] in ('rclpy', 'rcl_interfaces'):\n"
            "            raise ImportError('blocked ' + name)\n"
            "sys.meta_path.insert(0, Block())\n"
            "from online_em_slam.parameters.yaml_file import config_from_params\n"
            f"print(config_from_params({str(CAR_PARK_PARAMS)!r})[0].motion.model)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "acfr"


@pytest.mark.parametrize("make", ["plain_file", "truncated_mcap", "garbage_metadata", "params_not_yaml"])
def test_bad_files_give_one_line_naming_the_file_and_exit_1(tmp_path, capsys, make):
    """Reliability, second round, item 6: no traceback, exit status 1, the file named."""
    import shutil

    from online_em_slam.offline.cli import main
    from online_em_slam.datasets.kth.convert import convert

    good = tmp_path / "good"
    convert("car_park", good, progress=False)
    mcap = next(good.glob("*.mcap"))
    params = Path(__file__).resolve().parents[1] / "config" / "car_park.yaml"
    bag = tmp_path / make
    if make == "plain_file":
        bag.write_text("hello\n")
    elif make == "truncated_mcap":
        shutil.copytree(good, bag)
        data = (bag / mcap.name).read_bytes()
        (bag / mcap.name).write_bytes(data[: len(data) // 3])
    elif make == "garbage_metadata":
        shutil.copytree(good, bag)
        (bag / "metadata.yaml").write_text("garbage: {{{\n")
    else:
        bag, params = good, tmp_path / "params.yaml"
        params.write_text("x: [\n")
    code = main(["run", str(bag), "--params", str(params), "--output", str(tmp_path / "out"), "--no-plot"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1 and err.startswith("online-em-slam: error: ")
    assert str(bag if make != "params_not_yaml" else params) in err
