"""Map files: every kind of corruption is refused with one clear line and the
running estimate is left unchanged; saves are atomic (issue 12, defect 4 and
the kill -9 / fsync / predictable-temporary-name findings)."""
import copy
import io
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from online_em_slam.core.mapping import mapfile
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.experiments.simulation import ScenarioConfig, feed, simulate, slam_config_for


@pytest.fixture(scope="module")
def mapped_once():
    scenario = simulate(ScenarioConfig(seed=0, n_steps=60))
    config = slam_config_for(scenario)
    config.filter.num_particles = 20
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    return slam, scenario


@pytest.fixture
def mapped(mapped_once):
    """An estimator that has mapped a few landmarks (a copy per test: no test sees another's state)."""
    slam, scenario = mapped_once
    return copy.deepcopy(slam), scenario


def saved_arrays(slam, tmp_path) -> dict:
    path = tmp_path / "good.npz"
    slam.save_map(path)
    with np.load(path) as data:
        return {k: np.array(data[k]) for k in data.files}


def write_npz(path, arrays):
    np.savez(path, **arrays)
    return path


def snapshot(slam) -> dict:
    lm = slam.landmarks()
    poses, weights = slam.particles()
    return {"ids": lm.ids, "positions": lm.positions, "cov": lm.covariances, "n_obs": lm.n_obs,
            "pose": slam.pose().mean, "particles": poses, "weights": weights,
            "step": slam.step_count, "stamp": slam.last_stamp}


def assert_same(a, b) -> None:
    for key in a:
        np.testing.assert_array_equal(np.asarray(a[key]), np.asarray(b[key]), err_msg=key)


def _modified(**changes):
    def make(arrays, path):
        data = dict(arrays)
        for key, value in changes.items():
            if value is None:
                data.pop(key)
            else:
                data[key] = value(data) if callable(value) else value
        return write_npz(path, data)
    return make


def _truncated(fraction):
    def make(arrays, path):
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        raw = buffer.getvalue()
        path.write_bytes(raw[: int(len(raw) * fraction)])
        return path
    return make


def _flipped_bytes(arrays, path):
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    raw = bytearray(buffer.getvalue())
    with zipfile.ZipFile(io.BytesIO(bytes(raw))) as archive:
        info = archive.getinfo("theta.npy")
    start = info.header_offset + 30 + len(info.filename) + 140       # inside theta's data
    raw[start:start + 16] = b"\xff" * 16
    path.write_bytes(bytes(raw))
    return path


def _huge_header(arrays, path):
    """theta's header declares 10^9 rows: refused before any allocation."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (10 ** 9, 2)})
    with zipfile.ZipFile(path, "w") as archive:
        for key, value in arrays.items():
            if key == "theta":
                archive.writestr("theta.npy", buffer.getvalue() + b"\0" * 64)
            else:
                member = io.BytesIO()
                np.save(member, value)
                archive.writestr(f"{key}.npy", member.getvalue())
    return path


def _object_array(arrays, path):
    data = dict(arrays)
    data["ids"] = np.array([object()] * len(arrays["ids"]), dtype=object)
    np.savez(path, **data)     # savez pickles object arrays; loading must not unpickle them
    return path


def _text(arrays, path):
    path.write_text("this is not a map\n")
    return path


def _empty(arrays, path):
    path.write_bytes(b"")
    return path


def _missing(arrays, path):
    return path.parent / "does_not_exist.npz"


def _directory(arrays, path):
    path.mkdir()
    return path


def _drop_row(name):
    return _modified(**{name: lambda d: d[name][:-1]})


CORRUPTIONS = {
    "inconsistent lengths (ids)": _drop_row("ids"),
    "inconsistent lengths (stats)": _drop_row("stats"),
    "theta with 3 columns": _modified(theta=lambda d: np.hstack([d["theta"], d["theta"][:, :1]])),
    "theta 1-D": _modified(theta=lambda d: d["theta"].reshape(-1)),
    "1-element pose": _modified(pose=np.array([1.0])),
    "NaN pose": _modified(pose=np.array([np.nan, 0.0, 0.0])),
    "inf pose": _modified(pose=np.array([0.0, np.inf, 0.0])),
    "NaN theta": _modified(theta=lambda d: np.where(np.arange(d["theta"].size).reshape(d["theta"].shape) == 0,
                                                    np.nan, d["theta"])),
    "spread of shape (M, 2)": _modified(spread=lambda d: d["spread"][:, 0]),
    "inf inv_n": _modified(inv_n=lambda d: np.full_like(d["inv_n"], np.inf)),
    "negative counts": _modified(n_obs=lambda d: -np.ones_like(d["n_obs"])),
    "repeated ids": _modified(ids=lambda d: np.zeros_like(d["ids"])),
    "float ids": _modified(ids=lambda d: d["ids"] + 0.5),
    "confirmed not boolean": _modified(confirmed=lambda d: np.full(d["confirmed"].shape, 2)),
    "theta of strings": _modified(theta=lambda d: np.full(d["theta"].shape, "x")),
    "missing key (stats)": _modified(stats=None),
    "missing version": _modified(version=None),
    "wrong version": _modified(version=np.array(2)),
    "version of shape (2,)": _modified(version=np.array([1, 1])),
    "truncated file": _truncated(0.5),
    "truncated to the header": _truncated(0.05),
    "empty file": _empty,
    "not an npz": _text,
    "corrupted bytes (CRC)": _flipped_bytes,
    "header declaring 10^9 rows": _huge_header,
    "object array (pickle)": _object_array,
    "file missing": _missing,
    "a directory": _directory,
}


@pytest.mark.parametrize("kind", list(CORRUPTIONS))
def test_corrupt_map_is_refused_and_the_estimate_is_unchanged(kind, mapped, tmp_path):
    slam, scenario = mapped
    arrays = saved_arrays(slam, tmp_path)
    path = CORRUPTIONS[kind](arrays, tmp_path / "bad.npz")
    before = snapshot(slam)
    with pytest.raises(ValueError) as error:
        slam.load_map(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message and len(message) < 300, message
    assert_same(before, snapshot(slam))
    # The estimate still runs.
    report = slam.add_observations(slam.last_stamp + 0.2, scenario.steps[5].observations())
    assert np.all(np.isfinite(slam.pose().mean)) and report.n_observations > 0


def test_read_map_names_the_problem(mapped, tmp_path):
    slam, _ = mapped
    arrays = saved_arrays(slam, tmp_path)
    cases = {"theta with 3 columns": "theta has shape", "1-element pose": "pose",
             "inconsistent lengths (ids)": "ids has shape", "NaN pose": "not finite",
             "wrong version": "version", "missing key (stats)": "missing array(s): stats",
             "not an npz": "not a complete .npz map archive", "header declaring 10^9 rows": "more than the limit"}
    for kind, expected in cases.items():
        path = CORRUPTIONS[kind](arrays, tmp_path / f"{kind}.npz")
        with pytest.raises(mapfile.MapFileError, match=expected.replace("^", r"\^").replace("(", r"\(")
                           .replace(")", r"\)")):
            mapfile.read_map(path)


def test_good_map_round_trip_and_load_limit(mapped, tmp_path):
    slam, _ = mapped
    path = tmp_path / "map.npz"
    slam.save_map(path)
    data = mapfile.read_map(path)
    assert data["theta"].shape == (len(slam.landmarks()), 2) and data["pose"].shape == (3,)
    with pytest.raises(mapfile.MapFileError, match="more than the limit of 1 landmarks"):
        mapfile.read_map(path, max_landmarks=1)


def test_save_refuses_a_non_finite_estimate_and_keeps_the_good_file(mapped, tmp_path):
    slam, _ = mapped
    path = tmp_path / "map.npz"
    slam.save_map(path)
    good = path.read_bytes()
    arrays = saved_arrays(slam, tmp_path)
    arrays["theta"] = arrays["theta"] * np.nan
    arrays.pop("version")
    with pytest.raises(ValueError, match="theta holds non-finite"):
        mapfile.write_map(path, arrays)
    assert path.read_bytes() == good
    assert sorted(os.listdir(tmp_path)) == ["good.npz", "map.npz"]


def test_atomic_write_fsyncs_and_uses_unpredictable_names(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
    created = []
    real_mkstemp = mapfile.tempfile.mkstemp
    monkeypatch.setattr(mapfile.tempfile, "mkstemp",
                        lambda **kw: (lambda r: (created.append(r[1]), r)[1])(real_mkstemp(**kw)))
    target = tmp_path / "metrics.json"
    mapfile.write_bytes_atomic(target, b"{}\n")
    assert target.read_bytes() == b"{}\n"
    assert len(synced) >= 2                    # the file before the rename, then the directory
    assert created and os.path.dirname(created[0]) == str(tmp_path)
    assert os.path.basename(created[0]) != "metrics.json.tmp"
    assert os.listdir(tmp_path) == ["metrics.json"]


def test_atomic_write_does_not_follow_a_planted_symlink(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    target = tmp_path / "metrics.json"
    (tmp_path / "metrics.json.tmp").symlink_to(victim)        # the old predictable name
    target.symlink_to(victim)                                 # and the target itself
    mapfile.write_bytes_atomic(target, b"{}\n")
    assert victim.read_text() == "precious\n"
    assert not target.is_symlink() and target.read_bytes() == b"{}\n"


def test_atomic_write_cleans_up_after_a_failed_write(tmp_path):
    target = tmp_path / "map.npz"
    target.write_bytes(b"old")

    def fail(handle):
        handle.write(b"partial")
        raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        mapfile.write_file_atomic(target, fail)
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["map.npz"]


def test_temporaries_of_a_killed_writer_are_removed_by_the_next_save(mapped, tmp_path):
    """kill -9 in the middle of a save: the target is intact, and the orphaned
    temporary file is removed by the next save."""
    slam, _ = mapped
    path = tmp_path / "map.npz"
    slam.save_map(path)
    good = path.read_bytes()
    script = (
        "import os, sys, numpy as np\n"
        "from online_em_slam.core.mapping import mapfile\n"
        "def stuck(handle):\n"
        "    handle.write(b'partial'); handle.flush(); print('writing', flush=True); sys.stdin.read()\n"
        f"mapfile.write_file_atomic({str(path)!r}, stuck)\n")
    child = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"writing"
        leftovers = [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
        assert len(leftovers) == 1 and not leftovers[0].startswith("map.npz")
        child.kill()
        child.wait(10)
    finally:
        if child.poll() is None:
            child.kill()
    assert path.read_bytes() == good
    assert any(n.endswith(".tmp") for n in os.listdir(tmp_path))      # what kill -9 leaves
    slam.save_map(path)
    assert sorted(os.listdir(tmp_path)) == ["map.npz"]
    mapfile.read_map(path)


def test_confined_path(tmp_path):
    root = tmp_path / "maps"
    root.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    assert mapfile.confined_path("a.npz", str(root)) == str(root / "a.npz")
    assert mapfile.confined_path(str(root / "sub" / "a.npz"), str(root)) == str(root / "sub" / "a.npz")
    (root / "link").symlink_to(outside)
    (root / "file_link.npz").symlink_to(outside / "x.npz")
    for name in ("../x.npz", "sub/../../x.npz", str(outside / "x.npz"), "link/x.npz", "file_link.npz",
                 "/etc/passwd", ".", ""):
        with pytest.raises(mapfile.MapFileError):
            mapfile.confined_path(name, str(root))


def test_metrics_json_is_not_written_through_a_planted_symlink(tmp_path):
    """report.json_dump (metrics.json of every run) used the predictable name metrics.json.tmp."""
    from online_em_slam.offline.report import json_dump
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (tmp_path / "metrics.json.tmp").symlink_to(victim)
    json_dump(tmp_path / "metrics.json", {"rmse": 1.0})
    assert victim.read_text() == "precious\n"
    assert (tmp_path / "metrics.json").read_text() == '{\n  "rmse": 1.0\n}\n'
    assert sorted(os.listdir(tmp_path)) == ["metrics.json", "metrics.json.tmp", "victim.txt"]


def test_a_relative_map_file_without_a_directory_is_resolved_once(tmp_path, monkeypatch):
    """Reliability, second round, item 5: map_file dir/sub/m.npz saved to dir/sub/dir/sub/m.npz."""
    monkeypatch.chdir(tmp_path)
    path = mapfile.confined_path(*mapfile.map_file_path("dir/sub/m.npz"))
    assert path == str(tmp_path / "dir" / "sub" / "m.npz")
    assert mapfile.confined_path(*mapfile.map_file_path("m.npz")) == str(tmp_path / "m.npz")
    assert mapfile.confined_path(*mapfile.map_file_path("sub/m.npz", str(tmp_path / "maps"))) == \
        str(tmp_path / "maps" / "sub" / "m.npz")
    with pytest.raises(mapfile.MapFileError, match="'..'"):
        mapfile.confined_path(*mapfile.map_file_path("../m.npz", str(tmp_path / "maps")))


@pytest.mark.parametrize("saved_by, loaded_by", [("observed", "complete"), ("complete", "observed"),
                                                 ("observed", "observed"), ("complete", "complete")])
def test_a_map_loads_into_either_m_step_and_stays_where_it_was(tmp_path, saved_by, loaded_by):
    """The file holds each landmark's estimate and information whatever M-step wrote it: a map
    saved by one M-step and loaded by the other keeps its landmarks through the next steps
    (the complete-data M-step solves theta = A^-1 b from the file's statistics)."""
    from dataclasses import replace

    scenario = simulate(ScenarioConfig(seed=0, n_steps=80))
    config = slam_config_for(scenario)
    config.filter.num_particles = 20
    config.filter.relocalisation_std = (0.0, 0.0, 0.0)      # the robot has not moved: the format alone
    saver = OnlineEMSlam(replace(config, em=replace(config.em, m_step=saved_by)),
                         initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps[:60]:
        feed(saver, step)
    path = tmp_path / "map.npz"
    saver.save_map(path)
    before = saver.landmarks()
    loader = OnlineEMSlam(replace(config, em=replace(config.em, m_step=loaded_by)),
                          initial_pose=scenario.initial_pose, stamp=0.0)
    loader.load_map(path)
    np.testing.assert_allclose(loader.landmarks().positions, before.positions)
    for step in scenario.steps[60:]:
        feed(loader, step)
    after = loader.landmarks()
    moved = np.linalg.norm(after.positions[:len(before.positions)] - before.positions, axis=1)
    assert moved.max() < 1.0, moved
