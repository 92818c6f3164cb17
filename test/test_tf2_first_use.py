"""tf2_msgs built on first use (online_em_slam.messages.tf2_build.first_use), with a fake build.

The real cmake + ninja build (about 20 s) is measured by hand in a fresh venv (docs/NODE.md);
here the decisions around it: one line when it cannot or did not work, no second attempt
after a failure until asked, one builder at a time, the replay's and the node's hooks.
"""
from __future__ import annotations

import fcntl
import subprocess
import sys
import threading
import time

import pytest

from online_em_slam.messages.tf2_build import first_use


class FakeTf2Msgs:
    """Stands for the import of tf2_msgs: importable once ``build`` ran."""

    def __init__(self, fail: Exception | None = None) -> None:
        self.built, self.calls, self.fail = False, 0, fail

    def available(self) -> bool:
        return self.built

    def build(self, prefix, workdir, log, output):
        self.calls += 1
        assert workdir == prefix / "build" / "tf2_msgs" and output.writable()
        if self.fail:
            raise self.fail
        self.built = True


@pytest.fixture
def fake(monkeypatch):
    tf2 = FakeTf2Msgs()
    monkeypatch.setattr(first_use, "available", tf2.available)
    monkeypatch.setattr(first_use.builder, "missing", lambda prefix: None)
    monkeypatch.setattr(first_use, "said_unavailable", False)
    monkeypatch.delenv(first_use.SKIP_VARIABLE, raising=False)
    return tf2


def test_builds_once_into_the_prefix_with_a_start_and_an_end_line(fake, tmp_path):
    lines = []
    assert first_use.ensure(log=lines.append, prefix=tmp_path, build=fake.build)
    assert fake.calls == 1 and len(lines) == 2
    assert lines[0].startswith(f"tf2_msgs: not importable: building it once into {tmp_path} (about 30 s; log ")
    assert lines[1].startswith(f"tf2_msgs: built into {tmp_path} in ") and lines[1].endswith("/tf available")
    assert first_use.ensure(log=lines.append, prefix=tmp_path, build=fake.build)      # importable now: nothing
    assert fake.calls == 1 and len(lines) == 2


def test_a_failed_build_is_one_line_and_not_tried_again_until_asked(fake, tmp_path):
    fake.fail = subprocess.CalledProcessError(1, ["cmake", "-S", "src"])
    lines, warnings = [], []
    assert not first_use.ensure(log=lines.append, warn=warnings.append, prefix=tmp_path, build=fake.build)
    assert len(warnings) == 1 and warnings[0].startswith("tf2_msgs: build failed (cmake exited with status 1; log ")
    assert "~/map_to_odom" in warnings[0] and "\n" not in warnings[0]
    assert (tmp_path / "build" / "tf2_msgs.failed").read_text().strip() == "cmake exited with status 1"
    # The same process: silent.  A later process (the node started again): one line, no build.
    assert not first_use.ensure(log=lines.append, warn=warnings.append, prefix=tmp_path, build=fake.build)
    assert len(warnings) == 1
    first_use.said_unavailable = False
    assert not first_use.ensure(log=lines.append, warn=warnings.append, prefix=tmp_path, build=fake.build)
    assert fake.calls == 1 and len(warnings) == 2
    assert "its build failed before (cmake exited with status 1" in warnings[1]
    assert "online-em-slam-tf2-msgs build" in warnings[1]
    fake.fail = None                                  # the build command retries, and clears the mark
    assert first_use.ensure(log=lines.append, prefix=tmp_path, retry=True, build=fake.build)
    assert fake.calls == 2 and not (tmp_path / "build" / "tf2_msgs.failed").exists()


def test_what_is_missing_is_one_line_with_the_fix_and_no_build(fake, tmp_path, monkeypatch):
    monkeypatch.setattr(first_use.builder, "missing",
                        lambda prefix: "no C compiler found (apt-get install build-essential, or set CC)")
    warnings = []
    assert not first_use.ensure(log=warnings.append, prefix=tmp_path, build=fake.build)
    assert fake.calls == 0 and warnings == [
        "tf2_msgs: not importable and cannot be built here (no C compiler found (apt-get install "
        f"build-essential, or set CC)): {first_use.UNAVAILABLE}"]
    assert not (tmp_path / "build").exists()


def test_the_skip_variable_turns_the_build_off(fake, tmp_path, monkeypatch):
    monkeypatch.setenv(first_use.SKIP_VARIABLE, "1")
    warnings = []
    assert not first_use.ensure(log=warnings.append, prefix=tmp_path, retry=True, build=fake.build)
    assert fake.calls == 0 and len(warnings) == 1 and first_use.SKIP_VARIABLE in warnings[0]


def test_a_second_process_waits_for_the_first_builder_then_imports(fake, tmp_path):
    """Two nodes started together: the one that finds the lock taken waits, says so once, and
    uses what the other built instead of building again."""
    place = first_use.Place(tmp_path)
    place.workdir.mkdir(parents=True)
    lines, result = [], []
    with open(place.lock, "a") as other:                    # the other process's lock
        fcntl.flock(other, fcntl.LOCK_EX)
        waiter = threading.Thread(target=lambda: result.append(
            first_use.ensure(log=lines.append, prefix=tmp_path, build=fake.build)))
        waiter.start()
        deadline = time.monotonic() + 10
        while not lines and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lines == ["tf2_msgs: another process is building it; waiting"]
        fake.built = True                                   # the other process finished
        fcntl.flock(other, fcntl.LOCK_UN)
    waiter.join(10)
    assert result == [True] and fake.calls == 0 and len(lines) == 1


def test_a_failed_step_names_the_first_error_of_its_log(fake, tmp_path):
    def broken(prefix, workdir, log, output):
        output.write("-- The C compiler identification is unknown\n"
                     "CMake Error at /v/share/cmake/Modules/CMakeDetermineCCompiler.cmake:48 (message):\n"
                     "  Could not find the compiler specified in the environment variable CC:\n\n"
                     "  /nonexistent/cc.\n\nCall Stack (most recent call first):\n  CMakeLists.txt:3\n")
        output.flush()
        raise subprocess.CalledProcessError(1, ["cmake"])
    warnings = []
    assert not first_use.ensure(log=lambda line: None, warn=warnings.append, prefix=tmp_path, build=broken)
    assert warnings[0].startswith("tf2_msgs: build failed (cmake exited with status 1: Could not find the "
                                  "compiler specified in the environment variable CC: /nonexistent/cc.; log ")
    log = tmp_path / "log.txt"
    log.write_text("[3/9] gcc -c x.c\nx.c:1:10: fatal error: Python.h: No such file or directory\n")
    assert first_use.first_error(log) == "x.c:1:10: fatal error: Python.h: No such file or directory"
    log.write_text("all fine\n")
    assert first_use.first_error(log) is None and first_use.first_error(tmp_path / "absent") is None


def test_failure_reasons_are_one_line():
    assert first_use.failure_reason(subprocess.CalledProcessError(2, ["ninja", "-C", "b"])) == \
        "ninja exited with status 2"
    assert first_use.failure_reason(subprocess.CalledProcessError(1, [sys.executable, "-m", "pip"])) == \
        "pip install of the build requirements exited with status 1"
    assert first_use.failure_reason(subprocess.TimeoutExpired(["cmake"], 900)) == "cmake timed out after 900 s"
    assert first_use.failure_reason(RuntimeError("first\nsecond")) == "first"


def test_the_replay_builds_tf2_msgs_when_a_bag_topic_needs_it(monkeypatch):
    """message_class (replay, record, topic tool) asks for the build on a tf2_msgs type only."""
    pytest.importorskip("rclpy")
    from online_em_slam.bag import replay
    calls = []
    monkeypatch.setattr(replay.first_use, "ensure", lambda log: calls.append(log) or False)
    monkeypatch.setitem(sys.modules, "tf2_msgs", None)          # None in sys.modules: ImportError
    monkeypatch.setitem(sys.modules, "tf2_msgs.msg", None)
    with pytest.raises(ImportError):
        replay.message_class("tf2_msgs/msg/TFMessage")
    assert len(calls) == 1
    with pytest.raises(ImportError):
        replay.message_class("nosuch_msgs/msg/Thing")
    assert len(calls) == 1


def test_the_node_builds_tf2_msgs_before_it_starts(monkeypatch):
    pytest.importorskip("rclpy")
    from online_em_slam.ros import node as node_module
    order = []
    monkeypatch.setattr(node_module, "ensure_tf2_msgs", lambda log, warn: order.append("tf2_msgs") or True)

    def stopped():
        order.append("node")
        raise KeyboardInterrupt
    monkeypatch.setattr(node_module, "OnlineEmSlamNode", stopped)
    assert node_module.main([]) == 0
    assert order == ["tf2_msgs", "node"]
