"""online-em-slam-mrclam-benchmark on a tiny synthetic MRCLAM directory (the layout of test_mrclam.py's
_write_dataset): 15 landmarks, a robot driving a circle, barcodes read from the ground truth."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from online_em_slam.datasets.mrclam import benchmark
from online_em_slam.datasets.mrclam.paired import paired_markdown, pairs_by_method
from online_em_slam.datasets.mrclam.table import best_cell, cells, paired_with_better_baseline, results_markdown

N_LANDMARKS = 15
SUBJECTS = np.arange(6, 6 + N_LANDMARKS)
BARCODES = {subject: 100 + subject for subject in SUBJECTS} | {1: 5, 2: 14}


def _write_dataset(directory: Path, robot: int = 1, seconds: float = 30.0) -> Path:
    """Odometry (v, w) and its exact ground truth at 50 Hz; a barcode reading every 0.2 s
    of each landmark within 3.5 m in front, with small noise (seeded)."""
    rng = np.random.default_rng(0)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "Barcodes.dat").write_text("# subject barcode\n" + "".join(
        f"{s} {b}\n" for s, b in sorted(BARCODES.items())))
    angles = 2 * np.pi * np.arange(N_LANDMARKS) / N_LANDMARKS
    radius = 2.0 + 1.2 * (np.arange(N_LANDMARKS) % 2)
    xy = np.column_stack([radius * np.cos(angles), 2.0 + radius * np.sin(angles)])
    (directory / "Landmark_Groundtruth.dat").write_text("# subject x y sx sy\n" + "".join(
        f"{s} {x:.4f} {y:.4f} 0.0001 0.0001\n" for s, (x, y) in zip(SUBJECTS, xy)))
    t = 0.02 * np.arange(int(seconds / 0.02) + 1)
    v, w = np.full(t.size, 0.4), np.full(t.size, 0.2)
    yaw = w[0] * t
    pose = np.column_stack([v[0] / w[0] * np.sin(yaw), v[0] / w[0] * (1 - np.cos(yaw)), yaw])
    np.savetxt(directory / f"Robot{robot}_Odometry.dat", np.column_stack([t, v, w]), fmt="%.6f")
    np.savetxt(directory / f"Robot{robot}_Groundtruth.dat", np.column_stack([t, pose]), fmt="%.6f")
    rows = []
    for k in range(0, t.size, 10):
        d = xy - pose[k, :2]
        ranges = np.hypot(d[:, 0], d[:, 1])
        bearings = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - pose[k, 2])))
        for j in np.flatnonzero((ranges < 3.5) & (np.abs(bearings) < 1.2)):
            rows.append((t[k], BARCODES[SUBJECTS[j]], ranges[j] + 0.02 * rng.standard_normal(),
                         bearings[j] + 0.01 * rng.standard_normal()))
    np.savetxt(directory / f"Robot{robot}_Measurement.dat", np.array(rows), fmt=["%.3f", "%d", "%.4f", "%.4f"])
    return directory


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("mrclam_benchmark")
    _write_dataset(root / "data" / "MRCLAM_Dataset1")
    argv = ["--data-dir", str(root / "data"), "--output", str(root / "out"), "--datasets", "1", "--robots", "1",
            "--seconds", "20", "--seeds", "0", "--ids", "known", "--methods", "online_em", "ekf_slam",
            "--jobs", "1", "--particles", "20"]
    code = benchmark.main(argv)
    return root / "out", argv, code


def test_results_files_and_rows(sweep, capsys):
    out, _, code = sweep
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    keys = [r["key"] for r in results["runs"]]
    run = "1_r1_20s_known"
    assert keys == [f"{run}/bag", f"{run}/online_em/seed0", f"{run}/ekf_slam/seed0", f"{run}/ekf_slam_learned/seed0"]
    assert all(r["status"] == "ok" for r in results["runs"]), results["runs"]
    assert (out / "bags" / run / "metadata.yaml").exists()
    for method in ("online_em", "ekf_slam", "ekf_slam_learned"):
        assert (out / "runs" / run / method / "seed0" / "metrics.json").exists()
    assert (out / "runs" / run / "online_em" / "seed0" / "map.png").exists()           # plotted: first seed
    assert not (out / "runs" / run / "ekf_slam_learned" / "seed0" / "map.png").exists()
    learned = json.loads((out / "runs" / run / "ekf_slam_learned" / "seed0" / "metrics.json").read_text())
    assert learned["benchmark"]["params"][-1].endswith("online_em/seed0/noise.yaml")
    em = next(r for r in results["runs"] if r["method"] == "online_em")
    assert em["n_true"] == N_LANDMARKS and em["matched"] >= 10 and em["landmark_shape"] < 0.5
    assert em["noise_learned"]["sigma_range"] > 0 and em["item_wall_s"] > 0
    text = (out / "results.md").read_text()
    assert "## 20 s, known ids" in text and "| 1 | 1 |" in text
    assert "| dataset | robot | online_em | ekf_slam |" in text
    assert "online EM shape RMSE <= the better of EKF-SLAM and FastSLAM 2.0: " in text
    assert "(no batch results)" in text and "- dataset 1 robot 1: online_em " in text


def test_resume_reuses_metrics(sweep, capsys):
    out, argv, _ = sweep
    run = out / "runs" / "1_r1_20s_known"
    stamps = {p: p.stat().st_mtime_ns for p in run.rglob("metrics.json")}
    assert len(stamps) == 3
    assert benchmark.main(argv) == 0
    assert {p: p.stat().st_mtime_ns for p in run.rglob("metrics.json")} == stamps
    results = json.loads((out / "results.json").read_text())
    assert [r["status"] for r in results["runs"]] == ["reused"] * 4
    assert "reused" in capsys.readouterr().out


def test_rescore_scores_existing_maps_by_id(sweep, capsys):
    out, argv, _ = sweep
    path = out / "runs" / "1_r1_20s_known" / "online_em" / "seed0" / "metrics.json"
    before = json.loads(path.read_text())
    assert before["landmarks"]["paired_by"] == "id"          # known ids: the runner scores by id
    before["landmarks"] = {"rmse": -1.0}                       # as an older evaluation would have left it
    path.write_text(json.dumps(before))
    assert benchmark.main(argv + ["--rescore"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert [r["status"] for r in results["runs"]][1:] == ["rescored"] * 3
    after = json.loads(path.read_text())["landmarks"]
    assert after["paired_by"] == "id" and after["n_true"] == N_LANDMARKS and after["rmse"] >= 0.0
    assert len(after["matches"]) == after["n_matched"] >= 10


def test_plan_covers_every_method_and_noise(tmp_path):
    (tmp_path / "MRCLAM_Dataset1.tar.xz").write_bytes(b"")
    args = benchmark.build_parser().parse_args(["--data-dir", str(tmp_path), "--output", str(tmp_path / "o"),
                                                "--datasets", "1", "--robots", "2", "--seeds", "0", "1"])
    items = benchmark.plan(args)
    keys = {item.key for item in items}
    known, unknown = "1_r2_600s_known", "1_r2_600s_unknown"
    for run in (known, unknown):
        for seed in (0, 1):
            for method in ("online_em", "online_em_complete", "fastslam2", "fastslam2_learned",
                           "marginal_slam", "marginal_slam_learned"):
                assert f"{run}/{method}/seed{seed}" in keys
        # Deterministic on the params' noise: once; on the learned noise, which each seed learns: every seed.
        assert f"{run}/ekf_slam/seed0" in keys and f"{run}/ekf_slam/seed1" not in keys
        assert f"{run}/ekf_slam_learned/seed0" in keys and f"{run}/ekf_slam_learned/seed1" in keys
    assert f"{known}/batch/seed0" in keys and f"{known}/batch/seed1" not in keys
    assert f"{known}/batch_learned/seed0" in keys and f"{known}/batch_learned/seed1" in keys
    assert not any(k.startswith(f"{unknown}/batch") for k in keys)
    by_key = {item.key: item for item in items}
    for method in ("ekf_slam", "batch"):
        assert by_key[f"{known}/{method}_learned/seed1"].params[-1].endswith(f"{known}/online_em/seed1/noise.yaml")
    learned = by_key[f"{known}/fastslam2_learned/seed1"]
    assert learned.after == (f"{known}/bag", f"{known}/online_em/seed1")
    assert learned.params[-1].endswith(f"runs/{known}/online_em/seed1/noise.yaml")
    complete = by_key[f"{known}/online_em_complete/seed0"]
    assert dict(complete.overrides) == {"em.m_step": "complete"}
    assert [i.key for i in items].index(f"{known}/online_em/seed1") < [i.key for i in items].index(learned.key)


def test_plan_of_a_later_window(tmp_path):
    """--start S0: the runs are named by their window and convert from it."""
    (tmp_path / "MRCLAM_Dataset9.tar.xz").write_bytes(b"")
    args = benchmark.build_parser().parse_args(["--data-dir", str(tmp_path), "--output", str(tmp_path / "o"),
                                                "--datasets", "9", "--robots", "4", "--seeds", "0",
                                                "--ids", "known", "--start", "600", "--methods", "online_em"])
    items = benchmark.plan(args)
    assert [item.key for item in items] == ["9_r4_600s_from600s_known/bag", "9_r4_600s_from600s_known/online_em/seed0"]
    assert {item.start for item in items} == {600}
    assert benchmark.record(items[0], "ok", {})["start"] == 600
    assert benchmark.record(items[1], "ok", {})["internal_errors"] == 0
    assert benchmark.record(items[1], "ok", {"runner_skipped": {"internal_error": 3}})["internal_errors"] == 3


def test_failed_need_skips_dependents(tmp_path):
    source = benchmark.Item("r/bag", "convert", "r", 1, 1, 20, "known", str(tmp_path / "bag"),
                            source=str(tmp_path / "missing"))
    run = benchmark.Item("r/ekf_slam/seed0", "run", "r", 1, 1, 20, "known", source.bag, method="ekf_slam",
                         seed=0, out=str(tmp_path / "run"), after=(source.key,))
    records = benchmark.run_all([source, run], jobs=1, log=lambda *a, **k: None)
    assert [r["status"] for r in records] == ["failed", "skipped"]
    assert "needs r/bag (failed)" in records[1]["error"]


def test_a_run_with_inputs_failed_inside_the_estimator_says_so(tmp_path, monkeypatch):
    """Such a run completes (each failing input dropped), but its line in the log must say so."""
    run = benchmark.Item("r/online_em/seed0", "run", "r", 1, 1, 20, "known", str(tmp_path / "bag"),
                         method="online_em", seed=0, out=str(tmp_path / "run"))
    monkeypatch.setattr(benchmark, "run_method", lambda item: {"runner_skipped": {"internal_error": 4}})
    (tmp_path / "run").mkdir()
    lines = []
    benchmark.run_all([run], jobs=1, log=lambda line, **k: lines.append(line))
    assert "r/online_em/seed0: ok" in lines[0] and "4 input(s) failed inside the estimator" in lines[0]


def test_better_noise_setting_and_summary():
    def rec(method, noise, seed, shape, matched, spurious):
        return {"kind": "run", "status": "ok", "seconds": 600, "ids": "known", "dataset": 1, "robot": 1,
                "method": method, "noise": noise, "seed": seed, "landmark_shape": shape, "landmark_rmse": shape,
                "trajectory_rmse": 0.1, "matched": matched, "n_true": 15, "spurious": spurious, "item_wall_s": 1.0,
                "key": f"{method}/{noise}/{seed}", "error": None}
    records = [rec("online_em", "params", 0, 0.10, 15, 0), rec("online_em", "params", 1, 0.12, 15, 0),
               rec("fastslam2", "params", 0, 0.05, 14, 0), rec("fastslam2", "learned", 0, 0.20, 15, 1),
               rec("batch", "params", 0, 0.08, 15, 0), rec("batch", "learned", 0, 0.04, 15, 0)]
    table = cells(records)
    assert best_cell(table, (600, "known", 1, 1), "fastslam2")["noise"] == "learned"     # 15/15 beats 14/15
    assert best_cell(table, (600, "known", 1, 1), "batch")["noise"] == "learned"
    meta = {"methods": ["online_em", "fastslam2", "batch"], "datasets": [1], "robots": [1], "seeds": [0, 1],
            "params": ["p.yaml"], "match_gate_m": 1.0, "wall_time_s": 1.0, "jobs": 1, "date": "today"}
    text = results_markdown(records, meta)
    assert "0.110 ± 0.010 · 15/15 · 0" in text and "0.200 (L) · 15/15 · 1" in text
    assert "FastSLAM 2.0: 1 of 1 runs" in text and "ratio (mean over runs): 2.75 over 1 runs" in text
    assert "online_em 15/15 ✓, 0 spurious ✓; fastslam2 15/15 ✓, 1 spurious ✗" in text
    assert "paired by seed (beyond two standard errors): ahead on 1, level on 0, behind on 0 runs" in text
    assert "| online_em | 1 | 0.110 |" in text and text.count("| n/a | n/a |") == 3    # no scale in these records
    records[0].update(landmark_scale=0.97, landmark_shape_scaled=0.04)
    records[1].update(landmark_scale=0.99, landmark_shape_scaled=0.06)
    assert "| 0.0 | 0.980 | 0.050 |" in results_markdown(records, meta)              # online EM's, over its seeds


def test_paired_with_the_better_baseline_seed_by_seed():
    """Online EM's seed k against the baseline on seed k's learned noise; a deterministic baseline's one
    run on the params' noise against every seed; two standard errors decide ahead, level or behind."""
    def rec(robot, method, noise, seed, shape):
        return {"kind": "run", "status": "ok", "seconds": 600, "ids": "known", "dataset": 9, "robot": robot,
                "method": method, "noise": noise, "seed": seed, "landmark_shape": shape, "landmark_rmse": shape,
                "trajectory_rmse": 0.1, "matched": 15, "n_true": 15, "spurious": 0, "item_wall_s": 1.0,
                "key": f"{robot}/{method}/{noise}/{seed}", "error": None}
    ours = {1: [0.10, 0.11, 0.12], 2: [0.10, 0.11, 0.12], 3: [0.10, 0.11, 0.12]}
    theirs = {1: [0.10, 0.12, 0.11], 2: [0.12, 0.13, 0.14], 3: [0.08, 0.09, 0.10]}     # level, behind us, ahead
    records = [rec(r, "online_em", "params", k, v) for r, values in ours.items() for k, v in enumerate(values)]
    records += [rec(r, "ekf_slam", "learned", k, v) for r, values in theirs.items() for k, v in enumerate(values)]
    records += [rec(r, "ekf_slam", "params", 0, 0.5) for r in ours]                   # the worse setting
    table = cells(records)
    runs = sorted({k[:4] for k in table})
    line = paired_with_better_baseline(records, table, runs)
    assert line.endswith("ahead on 1, level on 1, behind on 1 runs"), line
    records = [r for r in records if r["noise"] == "params"] + [rec(r, "fastslam2", "params", 0, 0.11) for r in ours]
    table = cells(records)            # EKF-SLAM's deterministic run, no learned setting: one value for every seed
    assert paired_with_better_baseline(records, table, runs).endswith("ahead on 0, level on 3, behind on 0 runs")


def test_paired_differences_pair_run_method_noise_and_seed():
    """B - A over the pairs done in both: a failed item, a seed in one file only and another
    method are left out; the mean and standard error are those of the per-pair differences."""
    def rec(run, seed, shape, status="ok", method="online_em"):
        return {"kind": "run", "status": status, "run": run, "method": method, "noise": "params", "seed": seed,
                "landmark_shape": shape, "landmark_rmse": 2 * shape, "trajectory_rmse": 0.5, "matched": 15}
    a = [rec("1_r1", 0, 0.10), rec("1_r1", 1, 0.12), rec("9_r4", 0, 0.20), rec("9_r4", 1, 0.30, status="failed"),
         rec("9_r4", 2, 0.25)]
    b = [rec("1_r1", 0, 0.08), rec("1_r1", 1, 0.13), rec("9_r4", 0, 0.26), rec("9_r4", 1, 0.10),
         rec("1_r1", 0, 0.50, method="ekf_slam")]
    groups = pairs_by_method(a, b)
    assert list(groups) == [("online_em", "params")] and len(groups["online_em", "params"]) == 3
    diffs = np.array([0.08 - 0.10, 0.13 - 0.12, 0.26 - 0.20])
    text = paired_markdown(a, b)
    assert f"paired difference {diffs.mean():+.4f} ± {diffs.std(ddof=1) / np.sqrt(3):.4f}" in text
    assert "| 1_r1 | 2 | 0.110 -> 0.105 |" in text and "| 9_r4 | 1 | 0.200 -> 0.260 |" in text
    assert "B's shape below A's on 1 of 2 runs" in text
    assert "No work item is done in both files." in paired_markdown(a, [])
    # 15/15 with none spurious on every paired seed: A has it on both runs, B not on 9_r4 (seed 0)
    for row in a + b:
        row.update(n_true=15, spurious=0)
    b[2].update(matched=14, spurious=1)
    assert "every landmark within 1 m and none spurious on every paired seed: 2 -> 1 of 2 runs" in paired_markdown(a, b)


def test_compare_over_chosen_seeds(tmp_path):
    """--seeds restricts --compare's pairs (a change made on seeds 0-1 confirmed on 2-4)."""
    def rec(seed, shape):
        return {"kind": "run", "status": "ok", "run": "1_r1", "method": "online_em", "noise": "params", "seed": seed,
                "landmark_shape": shape, "landmark_rmse": shape, "trajectory_rmse": 0.5, "matched": 15,
                "n_true": 15, "spurious": 0}
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"runs": [rec(s, 0.10) for s in range(5)]}))
    b.write_text(json.dumps({"runs": [rec(s, 0.05 if s < 2 else 0.11) for s in range(5)]}))
    from online_em_slam.datasets.mrclam.paired import compare_files
    assert "### online_em (params noise): 5 pairs" in compare_files(str(a), str(b))
    held_out = compare_files(str(a), str(b), [2, 3, 4])
    assert "3 pairs" in held_out and "paired difference +0.0100" in held_out


def test_compare_prints_the_paired_differences_of_two_results_files(sweep, capsys):
    out, _, _ = sweep
    capsys.readouterr()
    results = str(out / "results.json")
    assert benchmark.main(["--compare", results, results]) == 0
    text = capsys.readouterr().out
    assert "### online_em (params noise)" in text and "paired difference +0.0000 (one pair" in text
    assert benchmark.main(["--compare", results, str(out / "missing.json")]) == 1
    assert "error: --compare" in capsys.readouterr().err


def test_compare_with_after_a_run_prints_the_paired_differences(sweep, capsys):
    """The resumed sweep (every item reused) against its own earlier results: zero differences."""
    out, argv, _ = sweep
    earlier = out.parent / "earlier.json"
    earlier.write_text((out / "results.json").read_text())
    capsys.readouterr()
    assert benchmark.main(argv + ["--compare-with", str(earlier)]) == 0
    text = capsys.readouterr().out
    assert "## Paired differences" in text and "paired difference +0.0000 (one pair" in text


def test_run_method_batch_is_the_models_optimum_as_a_run(sweep, tmp_path):
    """``online-em-slam run BAG --method batch`` writes and scores the batch as a run; on the
    synthetic circle (small noise, exact odometry) every landmark comes out near its survey."""
    pytest.importorskip("gtsam")
    from online_em_slam.offline import cli
    out, _, code = sweep
    assert code == 0
    params = Path(__file__).resolve().parents[1] / "config" / "mrclam.yaml"
    assert cli.main(["run", str(out / "bags" / "1_r1_20s_known"), "--params", str(params), "--method", "batch",
                     "--output", str(tmp_path / "batch"), "--no-plot"]) == 0
    metrics = json.loads((tmp_path / "batch" / "metrics.json").read_text())
    assert metrics["method"] == "batch" and metrics["n_landmarks"] >= 10
    assert metrics["landmarks"]["n_spurious"] == 0 and metrics["landmarks"]["shape_error"] < 0.05
    rows = np.genfromtxt(tmp_path / "batch" / "trajectory.csv", delimiter=",", names=True)
    assert rows.size > 50 and np.all(np.diff(rows["t"]) > 0)


def test_a_dataset_is_found_as_its_directory_or_its_archive(tmp_path):
    """The directory first, then the archive: .zip as the dataset's site offers it, or .tar.xz."""
    (tmp_path / "MRCLAM_Dataset2.zip").write_bytes(b"")
    (tmp_path / "MRCLAM_Dataset9.tar.xz").write_bytes(b"")
    assert benchmark.dataset_source(tmp_path, 2).name == "MRCLAM_Dataset2.zip"
    assert benchmark.dataset_source(tmp_path, 9).name == "MRCLAM_Dataset9.tar.xz"
    (tmp_path / "MRCLAM_Dataset9").mkdir()
    assert benchmark.dataset_source(tmp_path, 9).name == "MRCLAM_Dataset9"
    with pytest.raises(FileNotFoundError, match="no MRCLAM_Dataset3 directory"):
        benchmark.dataset_source(tmp_path, 3)
