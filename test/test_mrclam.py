"""UTIAS MRCLAM loader and bag converter, on small synthetic .dat files (and Dataset 1 when present)."""
from __future__ import annotations

import math
import re
import tarfile
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from online_em_slam.messages.cloud import OBSERVATION_FIELDS, decode_message
from online_em_slam.datasets.mrclam import DROP_REASONS, load_mrclam
from online_em_slam.datasets.mrclam.convert import (STAMP_OFFSET, integrate_velocities, mrclam_streams,
                                                    write_mrclam_bag)

REAL_DATASET1 = Path(__file__).resolve().parents[1] / ".." / "shared" / "datasets" / "mrclam" / "MRCLAM_Dataset1.tar.xz"

BARCODES = """# Subject #    Barcode #
  1 \t   5
  2 \t  14
  3 \t  41
  4 \t  32
  5 \t  23
  6 \t  72
  7 \t  27
  8 \t  54
"""
LANDMARKS = """# Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]
  6 \t 1.5 \t 2.0 \t 0.0001 \t 0.0002
  7 \t -1.0 \t 3.0 \t 0.0001 \t 0.0002
  8 \t 4.0 \t -2.5 \t 0.0001 \t 0.0002
"""
# One row per messy case; the comment names the drop reason (or "kept").
MEASUREMENTS = """# time barcode range bearing
-0.5 72 2.0 0.1
0.5 14 2.0 0.1
0.5 72 2.0 0.1
0.5 27 3.0 -0.2
1.0 99 2.0 0.0
1.0 54 nan 0.0
1.5 54 0 0.0
1.5 54 -1 0.0
2.0 54 inf 0.0
2.0 27 2.5 nan
3.0 54 4.0 0.3
# a comment between rows
12.0 72 2.0 0.0
"""
EXPECTED_DROPS = {"before_odometry": 1, "after_odometry": 1, "unknown_barcode": 1, "other_robot": 1,
                  "bad_range": 4, "bad_bearing": 1}
V, W, N_ODOM = 0.1, 0.2, 501        # 10 s at 50 Hz; the robot waits for the first second


def _odometry_rows(n=N_ODOM):
    t = 0.02 * np.arange(n)
    moving = t >= 1.0
    return np.column_stack([t, np.where(moving, V, 0.0), np.where(moving, W, 0.0)])


def _write_dataset(directory: Path, robot: int = 1, odometry=None) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "Barcodes.dat").write_text(BARCODES)
    (directory / "Landmark_Groundtruth.dat").write_text(LANDMARKS)
    odo = _odometry_rows() if odometry is None else odometry
    np.savetxt(directory / f"Robot{robot}_Odometry.dat", odo, fmt="%.6g")
    gt = np.column_stack([odo[:, 0], 0.1 * odo[:, 0], -0.05 * odo[:, 0], 0.01 * odo[:, 0]])
    np.savetxt(directory / f"Robot{robot}_Groundtruth.dat", gt, fmt="%.6g")
    (directory / f"Robot{robot}_Measurement.dat").write_text(MEASUREMENTS)
    return directory


@pytest.fixture()
def dataset(tmp_path):
    return _write_dataset(tmp_path / "MRCLAM_Dataset1")


# --------------------------------------------------------------------------- loader

def test_drop_counts_for_each_messy_case(dataset):
    run = load_mrclam(dataset, 1)
    assert dict(run.drops) == EXPECTED_DROPS and set(run.drops) == set(DROP_REASONS)
    np.testing.assert_allclose(run.measurement_times, [0.5, 0.5, 3.0])
    assert list(run.measurement_subjects) == [6, 7, 8]
    np.testing.assert_allclose(run.measurement_range, [2.0, 3.0, 4.0])
    np.testing.assert_allclose(run.measurement_bearing, [0.1, -0.2, 0.3])
    assert len(run.odometry_times) == len(run.ground_truth_times) == N_ODOM
    assert run.ground_truth_poses.shape == (N_ODOM, 3)
    assert list(run.landmark_subjects) == [6, 7, 8] and run.landmark_xy[2] == pytest.approx([4.0, -2.5])
    assert sum(run.truncated.values()) == 0 and sum(run.retimed.values()) == 0


def test_sources_directory_parent_and_archive(dataset, tmp_path):
    tar_path = tmp_path / "MRCLAM_Dataset1.tar.xz"
    with tarfile.open(tar_path, "w:xz") as tar:
        tar.add(dataset, arcname="MRCLAM_Dataset1")
    zip_path = tmp_path / "MRCLAM_Dataset1.zip"         # the form the dataset's site offers
    with zipfile.ZipFile(zip_path, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(dataset.iterdir()):
            archive.write(path, f"MRCLAM_Dataset1/{path.name}")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    runs = [load_mrclam(dataset, 1), load_mrclam(tmp_path, 1), load_mrclam(tar_path, 1), load_mrclam(zip_path, 1)]
    assert sorted(p.name for p in tmp_path.rglob("*")) == before          # nothing extracted
    for run in runs[1:]:
        np.testing.assert_array_equal(run.odometry_v, runs[0].odometry_v)
        np.testing.assert_array_equal(run.measurement_subjects, runs[0].measurement_subjects)
        assert run.drops == runs[0].drops


def test_seconds_keeps_the_first_seconds_of_every_stream(dataset):
    run = load_mrclam(dataset, 1, seconds=2.0)
    assert len(run.odometry_times) == 100 and run.odometry_times[-1] == pytest.approx(1.98)
    assert len(run.ground_truth_times) == 100
    np.testing.assert_allclose(run.measurement_times, [0.5, 0.5])   # from 2.0 s on: cut, not dropped
    assert run.truncated == Counter(odometry=401, ground_truth=401, measurements=4)
    assert run.drops["after_odometry"] == 0 and run.drops["bad_range"] == 3


def test_start_keeps_a_later_window_of_every_stream(dataset):
    """--start: the window [start, start + seconds) of each stream; what lies before it is cut
    with the rest of the run, not dropped as 'before_odometry'."""
    run = load_mrclam(dataset, 1, seconds=2.0, start=2.5)
    assert run.start == 2.5
    assert len(run.odometry_times) == 100 and run.odometry_times[[0, -1]] == pytest.approx([2.5, 4.48])
    np.testing.assert_allclose(run.ground_truth_times[[0, -1]], [2.5, 4.48])
    np.testing.assert_allclose(run.measurement_times, [3.0])
    assert run.truncated == Counter(odometry=401, ground_truth=401, measurements=11)
    assert sum(run.drops.values()) == 0
    whole = load_mrclam(dataset, 1, start=2.5)                       # to the end of the run
    assert whole.odometry_times[-1] == pytest.approx(10.0) and whole.drops["after_odometry"] == 1


@pytest.mark.parametrize("start", [-1.0, math.nan, True])
def test_start_must_be_a_non_negative_number(dataset, start):
    with pytest.raises(ValueError, match="start must be"):
        load_mrclam(dataset, 1, start=start)


def test_start_after_the_run_is_a_clear_error(dataset):
    with pytest.raises(ValueError, match="no odometry sample 20 s or more after the first"):
        load_mrclam(dataset, 1, start=20.0)


def test_printed_times_rebuilt_on_the_50hz_grid(tmp_path):
    """From 1000 s on, 5 significant digits round the 50 Hz times to 0.1 s (as in the real files)."""
    t = 990.0 + 0.02 * np.arange(1000)
    printed = np.array([float(f"{v:.5g}") for v in t])
    assert len(np.unique(printed)) < len(t)                                # repeated times in the file
    odo = np.column_stack([printed, np.full(t.size, V), np.zeros(t.size)])
    directory = _write_dataset(tmp_path / "d", odometry=odo)
    run = load_mrclam(directory, 1)
    np.testing.assert_allclose(run.odometry_times, t, atol=1e-9)
    assert run.retimed["odometry"] == run.retimed["ground_truth"] == int(np.sum(np.abs(printed - t) > 1e-9)) > 0


def test_waiting_robot_stays_at_the_origin(dataset):
    run = load_mrclam(dataset, 1)
    poses = mrclam_streams(run).odom.poses
    waiting = run.odometry_times <= 1.0
    assert np.all(poses[waiting] == 0.0)


@pytest.mark.parametrize("robot", [0, 6, -1, 2.5, True])
def test_robot_must_be_one_to_five(dataset, robot):
    with pytest.raises(ValueError, match="robot must be one of 1-5"):
        load_mrclam(dataset, robot)


def test_missing_and_malformed_files(dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="Robot2_Odometry.dat"):
        load_mrclam(dataset, 2)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_mrclam(tmp_path / "nowhere", 1)
    with pytest.raises(ValueError, match="seconds"):
        load_mrclam(dataset, 1, seconds=-3)
    (dataset / "Robot1_Measurement.dat").write_text("0.5 72 two 0.1\n")
    with pytest.raises(ValueError, match=r"^Robot1_Measurement.dat: malformed: [^\n]*$"):
        load_mrclam(dataset, 1)
    (dataset / "Robot1_Measurement.dat").write_text("0.5 72 2.0\n")
    with pytest.raises(ValueError, match="Robot1_Measurement.dat: expected 4 columns, got 3"):
        load_mrclam(dataset, 1)
    np.savetxt(dataset / "Robot1_Odometry.dat", [[0.0, 0, 0], [1.0, 0, 0], [0.5, 0, 0]])
    with pytest.raises(ValueError, match="Robot1_Odometry.dat: time does not increase at data row 3"):
        load_mrclam(dataset, 1)
    (dataset / "Robot1_Odometry.dat").write_text("# nothing\n")
    with pytest.raises(ValueError, match="Robot1_Odometry.dat: no odometry samples"):
        load_mrclam(dataset, 1)


def test_ambiguous_directory_and_bad_archive(dataset, tmp_path):
    _write_dataset(tmp_path / "MRCLAM_Dataset9")
    with pytest.raises(ValueError, match="holds 2 MRCLAM_Dataset"):
        load_mrclam(tmp_path, 1)
    junk = tmp_path / "junk.tar.xz"
    junk.write_bytes(b"not an archive")
    with pytest.raises(ValueError, match="junk.tar.xz: not a readable zip or tar archive"):
        load_mrclam(junk, 1)


# --------------------------------------------------------------------------- odometry integration

def test_constant_velocities_end_on_the_exact_circle():
    rng = np.random.default_rng(0)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.5, 60))])      # irregular steps, up to 0.5 s
    v, w = 0.3, 0.4
    poses = integrate_velocities(t, np.full(t.size, v), np.full(t.size, w))
    radius, turned = v / w, w * (t - t[0])
    expected = np.column_stack([radius * np.sin(turned), radius * (1 - np.cos(turned))])
    np.testing.assert_allclose(poses[:, :2], expected, atol=1e-12)
    np.testing.assert_allclose(np.cos(poses[:, 2]), np.cos(turned), atol=1e-12)
    np.testing.assert_allclose(np.sin(poses[:, 2]), np.sin(turned), atol=1e-12)


def test_straight_run_and_commands_held_over_the_step():
    t = np.array([0.0, 1.0, 3.0, 4.0])
    poses = integrate_velocities(t, [1.0, 0.5, 2.0, 9.0], [0.0, 0.0, 0.0, 9.0])
    np.testing.assert_allclose(poses, [[0, 0, 0], [1, 0, 0], [2, 0, 0], [4, 0, 0]], atol=1e-15)
    # the last command is never applied; a turn in place changes only the heading
    turn = integrate_velocities([0.0, 1.0], [0.0, 0.0], [math.pi / 2, 0.0])
    np.testing.assert_allclose(turn[-1], [0.0, 0.0, math.pi / 2], atol=1e-15)


# --------------------------------------------------------------------------- bags

EXPECTED_COUNTS = {"/tf_static": 1, "/ground_truth/landmarks": 1, "/control": N_ODOM, "/odom": N_ODOM,
                   "/tf": N_ODOM, "/ground_truth/position": 101, "/ground_truth/pose": 101,
                   "/landmark_observations": 2}


def _read(path, topics=None):
    from online_em_slam.bag.bagio import read_bag
    return list(read_bag(path, topics))


def test_bag_round_trip(dataset, tmp_path):
    run = load_mrclam(dataset, 1)
    out = tmp_path / "bag"
    assert write_mrclam_bag(run, out, progress=False) == EXPECTED_COUNTS
    messages = _read(out)
    assert Counter(t for t, _, _ in messages) == EXPECTED_COUNTS
    stamps = np.array([s for _, s, _ in messages])
    # (header stamps and the log times of header-less /tf differ by float rounding at 1e9 s: 1.2e-7 s)
    assert np.all(np.diff(stamps) >= -1e-6) and stamps[0] == pytest.approx(STAMP_OFFSET)
    assert [t for t, _, _ in messages[:2]] == ["/tf_static", "/ground_truth/landmarks"]
    by_topic = {}
    for topic, stamp, msg in messages:
        by_topic.setdefault(topic, []).append((stamp, msg))
    (_, tf_static), = by_topic["/tf_static"]
    assert [(t.header.frame_id, t.child_frame_id) for t in tf_static.transforms] == [("base_link", "camera")]
    (_, gt_lm), = by_topic["/ground_truth/landmarks"]
    cols = decode_message(gt_lm, required=("x", "y", "z", "id"))
    assert gt_lm.header.frame_id == "map" and list(cols["id"]) == [6, 7, 8]
    np.testing.assert_allclose(np.column_stack([cols["x"], cols["y"]]), run.landmark_xy, atol=1e-6)
    clouds = by_topic["/landmark_observations"]
    assert [s - STAMP_OFFSET for s, _ in clouds] == pytest.approx([0.5, 3.0], abs=1e-6)
    first = decode_message(clouds[0][1], required=[n for n, _ in OBSERVATION_FIELDS])
    assert clouds[0][1].header.frame_id == "camera" and list(first["id"]) == [6, 7]
    np.testing.assert_allclose(first["range"], [2.0, 3.0], rtol=1e-6)
    np.testing.assert_allclose(first["bearing"], [0.1, -0.2], rtol=1e-6)
    assert np.all(first["range_std"] == 0) and np.all(first["bearing_std"] == 0)
    odom = by_topic["/odom"]
    expected = mrclam_streams(run).odom.poses[-1]
    last = odom[-1][1]
    assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
    assert (last.pose.pose.position.x, last.pose.pose.position.y) == pytest.approx(tuple(expected[:2]))
    assert last.twist.twist.linear.x == V and last.twist.twist.angular.z == W
    assert odom[-1][0] - STAMP_OFFSET == pytest.approx(10.0, abs=1e-6)
    control = by_topic["/control"][-1][1]
    assert control.header.frame_id == "base_link" and (control.twist.linear.x, control.twist.angular.z) == (V, W)
    tf = by_topic["/tf"][-1][1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("odom", "base_link")
    gt_times = np.array([s for s, _ in by_topic["/ground_truth/pose"]]) - STAMP_OFFSET
    np.testing.assert_allclose(gt_times, 0.1 * np.arange(101), atol=1e-6)                # every 5th sample
    pose = by_topic["/ground_truth/pose"][10][1]
    assert pose.header.frame_id == "map" and pose.pose.position.x == pytest.approx(0.1)
    assert 2 * math.atan2(pose.pose.orientation.z, pose.pose.orientation.w) == pytest.approx(0.01)
    point = by_topic["/ground_truth/position"][10][1]
    assert point.header.frame_id == "map" and (point.point.x, point.point.y) == pytest.approx((0.1, -0.05))


def test_bag_unknown_ids_sqlite_and_overwrite(dataset, tmp_path):
    run = load_mrclam(dataset, 1)
    out = tmp_path / "bag"
    write_mrclam_bag(run, out, storage="sqlite3", unknown_ids=True, progress=False)
    assert list(out.glob("*.db3"))
    ids = [decode_message(m)["id"] for _, _, m in _read(out, ["/landmark_observations"])]
    assert [list(i) for i in ids] == [[-1, -1], [-1]]
    with pytest.raises(FileExistsError):
        write_mrclam_bag(run, out, progress=False)
    write_mrclam_bag(run, out, overwrite=True, progress=False)
    assert list(out.glob("*.mcap"))


# --------------------------------------------------------------------------- command line

def _cli(argv, capsys):
    from online_em_slam.datasets.convert import main
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_converts_and_prints_counts_and_drops(dataset, tmp_path, capsys):
    out = tmp_path / "bag"
    code, text, err = _cli(["mrclam", str(out), "--data-dir", str(dataset), "--robot", "1", "--no-progress"],
                           capsys)
    assert code == 0 and err == ""
    assert re.search(rf"^/odom +{N_ODOM}$", text, re.M) and re.search(r"^/landmark_observations +2$", text, re.M)
    assert "other_robot 1" in text and "bad_range 4" in text and "kept 3" in text
    assert f"wrote {sum(EXPECTED_COUNTS.values())} messages" in text


@pytest.mark.parametrize("extra, message", [
    (["--robot", "7"], "robot must be one of 1-5, got 7"),
    ([], "mrclam needs --robot"),
    (["--robot", "2"], "Robot2_Odometry.dat"),
    (["--robot", "1", "--seconds", "0"], "seconds must be a positive number"),
    (["--robot", "1", "--no-map-to-gps"], "--no-map-to-gps is for the KTH datasets"),
])
def test_cli_error_lines(dataset, tmp_path, capsys, extra, message):
    code, _, err = _cli(["mrclam", str(tmp_path / "bag"), "--data-dir", str(dataset), *extra], capsys)
    assert code == 1 and message in err
    assert err.count("\n") == 1 and err.startswith("online-em-slam-convert: error: ")


def test_cli_other_errors(dataset, tmp_path, capsys):
    code, _, err = _cli(["mrclam", str(tmp_path / "bag"), "--robot", "1"], capsys)
    assert code == 1 and "mrclam needs --data-dir" in err and err.count("\n") == 1
    code, _, err = _cli(["car_park", str(tmp_path / "cp"), "--robot", "1"], capsys)
    assert code == 1 and "for mrclam only" in err and err.count("\n") == 1
    assert not (tmp_path / "cp").exists()
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "keep.txt").write_text("x")
    code, _, err = _cli(["mrclam", str(tmp_path / "bag"), "--data-dir", str(dataset), "--robot", "1"], capsys)
    assert code == 1 and "exists" in err and err.count("\n") == 1


@pytest.mark.skipif(not REAL_DATASET1.is_file(), reason=f"{REAL_DATASET1} not present")
def test_real_dataset1_robot1_first_60_s(tmp_path, capsys):
    out = tmp_path / "d1r1"
    code, text, err = _cli(["mrclam", str(out), "--data-dir", str(REAL_DATASET1), "--robot", "1",
                            "--seconds", "60", "--no-progress"], capsys)
    assert code == 0, err
    from online_em_slam.bag.bagio import bag_topics
    counts = {t: n for t, (_, n) in bag_topics(out).items()}
    assert counts["/odom"] == counts["/control"] == counts["/tf"] == 3000
    assert counts["/ground_truth/position"] == counts["/ground_truth/pose"] == 600
    assert counts["/landmark_observations"] == 80
    assert "other_robot 83" in text and "kept 123" in text
    ids = np.concatenate([decode_message(m)["id"] for _, _, m in _read(out, ["/landmark_observations"])])
    assert ids.size == 123 and set(ids.tolist()) <= set(range(6, 21))


def test_runner_starts_at_the_first_ground_truth_pose(dataset, tmp_path):
    from online_em_slam.parameters.yaml_file import config_from_params, load_params
    from online_em_slam.offline.runner import choose_initial_pose, read_inputs

    bag = tmp_path / "bag"
    write_mrclam_bag(load_mrclam(dataset, 1), bag, progress=False)
    values = load_params(Path(__file__).resolve().parents[1] / "config" / "mrclam.yaml")
    config, settings = config_from_params(values, {})
    inputs = read_inputs(bag, settings)
    initial = choose_initial_pose("auto", inputs, config, settings, values)
    assert initial.source.startswith("/ground_truth/pose")
    assert initial.pose == pytest.approx(tuple(inputs.gt_poses[0]))
    assert inputs.gt_pose_times[0] <= initial.stamp


def test_swapped_survey_labels_are_found_and_corrected(tmp_path):
    """Subjects 6 and 8 swapped in Landmark_Groundtruth.dat (as 11 and 17 are in Dataset 1):
    the measurements placed from the ground-truth poses sit on the other entry, so the loader
    relabels the survey and the converter says so; a correct survey is left as it is."""
    from online_em_slam.datasets.mrclam.convert import report_lines
    from online_em_slam.datasets.mrclam.survey import median_placements

    directory = _write_dataset(tmp_path / "swapped")
    survey = {6: (1.5, 2.0), 7: (-1.0, 3.0), 8: (4.0, -2.5)}
    t = np.arange(1.0, 9.0, 0.25)
    gt = np.loadtxt(directory / "Robot1_Groundtruth.dat")
    rows = []
    for subject, barcode in ((6, 72), (7, 27), (8, 54)):
        x, y, yaw = (np.interp(t, gt[:, 0], gt[:, k]) for k in (1, 2, 3))
        dx, dy = survey[subject][0] - x, survey[subject][1] - y
        rows += [(ti, barcode, r, b) for ti, r, b in zip(t, np.hypot(dx, dy), np.arctan2(dy, dx) - yaw)]
    np.savetxt(directory / "Robot1_Measurement.dat", np.array(sorted(rows)), fmt=["%.3f", "%d", "%.6f", "%.6f"])
    right = load_mrclam(directory, 1)
    assert right.survey_relabelled == {}
    placed = median_placements(right)
    assert all(np.hypot(*(placed[s] - survey[s])) < 1e-3 for s in survey)
    (directory / "Landmark_Groundtruth.dat").write_text(LANDMARKS.replace("  6 ", "  X ").replace("  8 ", "  6 ")
                                                         .replace("  X ", "  8 "))
    run = load_mrclam(directory, 1)
    assert run.survey_relabelled == {6: 8, 8: 6}
    assert dict(zip(run.landmark_subjects.tolist(), map(tuple, run.landmark_xy))) == survey
    assert "subject 6 was listed as 8" in report_lines(run)[-1]


@pytest.mark.skipif(not REAL_DATASET1.is_file(), reason=f"{REAL_DATASET1} not present")
def test_real_dataset1_later_window_keeps_the_survey_correction(tmp_path, capsys):
    """A window from 600 s: the survey's swap of subjects 11 and 17 is found from the whole run."""
    out = tmp_path / "d1r1_w2"
    code, text, err = _cli(["mrclam", str(out), "--data-dir", str(REAL_DATASET1), "--robot", "1",
                            "--seconds", "60", "--start", "600", "--no-progress"], capsys)
    assert code == 0, err
    assert "60 s from 600 s after the first odometry sample kept" in text
    assert "subject 11 was listed as 17" in text
    first = _read(out, ["/ground_truth/pose"])[0]
    assert first[1] == pytest.approx(STAMP_OFFSET + 600.0, abs=1e-3)          # seconds


def test_start_is_for_one_robot(dataset, tmp_path, capsys):
    code, _, err = _cli(["mrclam", str(tmp_path / "f"), "--data-dir", str(dataset), "--all-robots",
                         "--start", "2", "--no-progress"], capsys)
    assert code == 1 and "--start is for one robot" in err
