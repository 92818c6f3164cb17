"""The benchmark's long-run experiment, configuration overrides and paired comparison."""
import json
import math

import numpy as np
import pytest

from online_em_slam.experiments import benchmark, benchmark_tables
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for


def test_overrides_are_typed_validated_and_reach_the_online_em_config():
    assert benchmark.parse_override("em.segment_length=25") == ("em", "segment_length", 25)
    assert benchmark.parse_override("noise.mixture_weights=[0.9, 0.1]")[2] == [0.9, 0.1]
    config = benchmark.apply_overrides(slam_config_for(ScenarioConfig()),
                                       ["em.m_step=observed", "em.segment_length=25", "filter.num_particles=7"])
    assert (config.em.m_step, config.em.segment_length, config.filter.num_particles) == ("observed", 25, 7)
    for bad in ("em.m_step", "em=3", "nosuch.key=1", "em.nosuch=1", "em.m_step=bad"):
        with pytest.raises(ValueError):
            benchmark.apply_overrides(slam_config_for(ScenarioConfig()), [bad])
    scenario = simulate(ScenarioConfig(n_steps=5))
    estimator = benchmark.make_estimator("online_em_complete_paris", slam_config_for(scenario, 10), scenario,
                                         ["em.segment_length=4"])
    assert estimator.config.em.segment_length == 4 and estimator.config.filter.smoother == "paris"


def test_lap_checkpoints_of_a_long_run_equal_the_shorter_runs():
    """Scoring after lap 1 of a 2-lap run gives exactly the 1-lap run's scores."""
    long = benchmark.run_one(benchmark.Job("ekf_slam", 3, 10, 0, laps=(2,)))
    short = benchmark.run_one(benchmark.Job("ekf_slam", 3, 10, 0, laps=(1,)))
    assert [r["laps"] for r in long] == [1, 2] and len(short) == 1
    for key in ("landmark_rmse", "shape_error", "frame_error", "pose_rmse", "mean_nees", "n_steps"):
        assert long[0][key] == short[0][key], key
    assert long[1]["n_steps"] == 2 * long[0]["n_steps"]
    row = long[1]
    assert row["landmark_rmse"] ** 2 == pytest.approx(row["shape_error"] ** 2 + row["frame_error"] ** 2)
    assert 0.0 <= row["shape_error"] <= row["landmark_rmse"]


def _row(method, seed, laps, rmse, shape=0.1, frame=0.2):
    return {"method": method, "seed": seed, "laps": laps, "landmark_rmse": rmse, "shape_error": shape,
            "frame_error": frame, "pose_rmse": 1.0, "mean_step_ms": 1.0, "p99_step_ms": 2.0,
            "mean_nees": math.nan, "mean_true_pose_loglik": math.nan, "n_steps": 510 * laps}


def test_summary_and_paired_differences_by_method_laps_and_seed():
    a = [_row("ekf_slam", s, 1, 2.0 + s) for s in range(4)] + [_row("online_em", 0, 1, 5.0)]
    b = [_row("ekf_slam", s, 1, 1.5 + s + 0.1 * (s % 2)) for s in range(5)]       # seed 4 has no pair
    table = benchmark_tables.summarize(a)
    ekf = next(r for r in table if r["method"] == "ekf_slam")
    assert ekf["runs"] == 4 and ekf["landmark_rmse_mean"] == pytest.approx(3.5)
    assert ekf["landmark_rmse_se"] == pytest.approx(np.std([2, 3, 4, 5], ddof=1) / 2)
    [paired] = benchmark_tables.paired_differences(a, b)
    assert (paired["method"], paired["laps"], paired["runs"]) == ("ekf_slam", 1, 4)
    diffs = np.array([-0.5, -0.4, -0.5, -0.4])
    assert paired["landmark_rmse_mean"] == pytest.approx(diffs.mean())
    assert paired["landmark_rmse_se"] == pytest.approx(diffs.std(ddof=1) / 2)
    assert paired["shape_error_mean"] == 0.0
    text = benchmark_tables.format_paired([paired], "a", "b")
    assert "| ekf_slam | 1 | 4 | 3.500 -> 3.050 | -0.450 ± 0.029 |" in text
    assert "| ekf_slam | 1 | 4 | 510 | 3.500 ± 0.645 |" in benchmark_tables.format_laps_table(table, [1])


def test_laps_command_writes_table_json_and_plot_and_compares_variants(tmp_path, capsys):
    common = ["--runs", "2", "--laps", "1", "--methods", "ekf_slam", "--output", str(tmp_path)]
    assert benchmark.main(common + ["--tag", "a"]) == 0
    assert benchmark.main(common + ["--tag", "b", "--set", "em.segment_length=5",
                                    "--compare-with", str(tmp_path / "results-a.json")]) == 0
    out = capsys.readouterr().out
    assert "| method | laps | runs | steps | landmark RMSE (m) | shape (m) | frame (m) |" in out
    assert "Paired differences b - a" in out and "| 0.000 ± 0.000 |" in out     # the EKF ignores --set
    data = json.loads((tmp_path / "results-b.json").read_text())
    assert data["meta"]["overrides"] == ["em.segment_length=5"] and data["meta"]["laps"] == [1]
    assert {r["seed"] for r in data["runs"]} == {0, 1}
    assert (tmp_path / "laps_error-b.png").stat().st_size > 10_000 and (tmp_path / "table-b.md").exists()
    assert benchmark.main(["--compare", str(tmp_path / "results-a.json"), str(tmp_path / "results-b.json")]) == 0
    with pytest.raises(SystemExit):
        benchmark.main(["--set", "em.nosuch=1", "--output", str(tmp_path)])
