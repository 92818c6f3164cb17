"""Issue 23 item 9: an existing output names the real fix (the flag as typed, or a new name)."""
import sys

from online_em_slam.bag import record
from online_em_slam.datasets import convert


def test_converter_names_the_overwrite_flag_and_replaces_with_it(tmp_path, capsys):
    out = tmp_path / "bag"
    assert convert.main(["car_park", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert convert.main(["car_park", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err == f"online-em-slam-convert: error: {out} exists (use --overwrite)\n"
    assert convert.main(["car_park", str(out), "--no-progress", "--overwrite"]) == 0


def test_recorder_refuses_an_existing_output_with_the_fix(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["online-em-slam-record"])
    assert record.main([str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"online-em-slam-record: error: {tmp_path} exists (give a new OUTPUT")
    assert err.count("\n") == 1
