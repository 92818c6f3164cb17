"""Shape and frame error in the offline runner's printed summary and comparison table."""
from online_em_slam.offline import report


def _metrics(method: str) -> dict:
    return {"method": method, "n_landmarks": 16, "n_confirmed_landmarks": 15,
            "landmarks": {"n_matched": 15, "n_true": 15, "n_spurious": 1, "rmse": 0.25,
                          "shape_error": 0.15, "frame_error": 0.2},
            "timing": {"mean_step_ms": 1.0, "p99_step_ms": 2.0, "real_time_factor": 100.0,
                       "wall_time_s": 1.25, "dataset_duration_s": 125.0}}


def test_summary_and_comparison_report_shape_and_frame():
    assert "RMSE 0.250 m (shape 0.150, frame 0.200)" in report.summary_line(_metrics("online_em"))
    rows = [report.comparison_row(_metrics("online_em")), report.comparison_row(_metrics("ekf_slam"))]
    assert rows[0]["beacon_shape_error_m"] == 0.15 and rows[0]["beacon_frame_error_m"] == 0.2
    text = report.comparison_markdown(rows, "bag", "params.yaml", 0, 100)
    assert "| beacon RMSE (m) | shape (m) | frame (m) |" in text
    assert "| ekf_slam | 15/15 | 1 | 0.250 | 0.150 | 0.200 |" in text


def test_summary_names_the_map_scale_only_when_it_is_off():
    metrics = _metrics("online_em")
    metrics["landmarks"].update(map_scale=0.974, scaled_shape_error=0.05)
    assert "frame 0.200), map scale 0.974 (shape without it 0.050);" in report.summary_line(metrics)
    metrics["landmarks"]["map_scale"] = 1.003
    assert "map scale" not in report.summary_line(metrics)
    assert "map scale" not in report.summary_line(_metrics("online_em"))        # older metrics: no scale
