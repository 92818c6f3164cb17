"""tf2_msgs on first use: built once into this Python environment, or one line saying why not.

:func:`ensure` is what the node's ``main`` and the bag tools call before they need
tf2_msgs/TFMessage.  When ``tf2_msgs.msg`` imports (a real Jazzy install, or built
before) it returns at once.  Otherwise it builds it into ``sys.prefix`` (about 20-40 s,
once), under a lock in ``PREFIX/build/tf2_msgs.lock`` so that two processes started
together build it once (the second waits, then imports).  Whatever prevents it is one
line (what is missing and the fix, or the failed step and the log file) and False: the
node then sends map -> odom on ``~/map_to_odom`` and the replay skips /tf.  A build that
failed leaves ``PREFIX/build/tf2_msgs.failed`` so later starts do not try again (one
line instead); ``online-em-slam-tf2-msgs build`` retries.  ``ONLINE_EM_SLAM_NO_TF2_MSGS=1``
turns the build off (first use, the command and ``make install``).
"""
from __future__ import annotations

import contextlib
import dataclasses
import importlib
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

from . import build as builder

SKIP_VARIABLE = "ONLINE_EM_SLAM_NO_TF2_MSGS"
UNAVAILABLE = "no /tf (the node sends map -> odom on ~/map_to_odom; the replay skips /tf and /tf_static)"
LOCK_TIMEOUT = 900.0
#: Set when this process was told why tf2_msgs is unavailable: later calls stay silent.
said_unavailable = False


def available() -> bool:
    """``tf2_msgs.msg.TFMessage`` imports in this process (import caches refreshed first)."""
    importlib.invalidate_caches()
    try:
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415
    except ImportError:
        return False
    return TFMessage is not None


@dataclasses.dataclass(frozen=True)
class Place:
    """Where a build into ``prefix`` keeps its files."""

    prefix: Path

    def _build(self, suffix: str) -> Path:
        return self.prefix / "build" / f"tf2_msgs{suffix}"

    workdir = property(lambda self: self._build(""))
    log = property(lambda self: self._build(".log"))
    lock = property(lambda self: self._build(".lock"))
    failed = property(lambda self: self._build(".failed"))


@contextlib.contextmanager
def exclusive(path: Path, log, timeout: float = LOCK_TIMEOUT):
    """Hold an exclusive lock on ``path`` (waits for another builder, says so once)."""
    import fcntl  # noqa: PLC0415 (POSIX; the ROS wheels are Linux-only)
    with open(path, "a") as handle:
        deadline, said = time.monotonic() + timeout, False
        while True:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"another process held {path} for {timeout:.0f} s") from None
                if not said:
                    log("tf2_msgs: another process is building it; waiting")
                    said = True
                time.sleep(0.5)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def failure_reason(error: BaseException) -> str:
    """One line for a failed step."""
    if isinstance(error, subprocess.CalledProcessError):
        command = error.cmd[0] if isinstance(error.cmd, (list, tuple)) else str(error.cmd)
        if command == sys.executable:
            command = "pip install of the build requirements"
        return f"{Path(str(command)).name} exited with status {error.returncode}"
    if isinstance(error, subprocess.TimeoutExpired):
        return f"{Path(str(error.cmd[0])).name} timed out after {error.timeout:.0f} s"
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


def first_error(log_file: Path, width: int = 120) -> str | None:
    """The first error a build log reports (CMake's, the compiler's, pip's), shortened to one line."""
    try:
        lines = [line.strip() for line in Path(log_file).read_text(errors="replace").splitlines()]
    except OSError:
        return None
    for k, text in enumerate(lines):
        if text.startswith("CMake Error at"):            # the message follows, up to the call stack
            message = itertools.takewhile(lambda line: not line.startswith("Call Stack"), lines[k + 1:k + 8])
            text = " ".join(line for line in message if line) or text
        elif "error" not in text.lower() or text.startswith("-- "):
            continue
        text = text.removeprefix("CMake Error: ").removeprefix("ERROR: ")
        return text if len(text) <= width else text[:width - 3] + "..."
    return None


def ensure(log=print, prefix: Path | None = None, retry: bool = False, install_requirements: bool = False,
           force: bool = False, build=builder.build, warn=None) -> bool:
    """tf2_msgs importable after this call? Builds it into ``prefix`` (default: this environment) if need be.

    ``retry``: build even after an earlier failure (the ``build`` command); ``install_requirements``:
    pip install the build requirements first (``make install``); ``force``: rebuild even when
    tf2_msgs imports; ``warn``: where the line saying why tf2_msgs is unavailable goes (default:
    ``log``).  That line is said once per process."""
    global said_unavailable
    if not force and available():
        return True
    if said_unavailable and not (retry or force):
        return False
    place = Place(Path(prefix or sys.prefix).resolve())
    refusal = refused(place, retry, install_requirements)
    if refusal is None:
        refusal = run_build(place, log, force, install_requirements, build)
    if refusal is not None:
        (warn or log)(f"tf2_msgs: {refusal}: {UNAVAILABLE}")
    said_unavailable = refusal is not None
    return refusal is None


def refused(place: Place, retry: bool, install_requirements: bool) -> str | None:
    """Why no build is tried now (checked before taking the lock), or None."""
    if os.environ.get(SKIP_VARIABLE):
        return f"not importable and not built ({SKIP_VARIABLE} is set)"
    if place.failed.is_file() and not retry:
        reason = place.failed.read_text().strip() or "unknown"
        return (f"not importable; its build failed before ({reason}; log {place.log}; "
                "`online-em-slam-tf2-msgs build` tries again)")
    reason = None if install_requirements else builder.missing(place.prefix)
    return None if reason is None else f"not importable and cannot be built here ({reason})"


def run_build(place: Place, log, force: bool, install_requirements: bool, build) -> str | None:
    """Build under the lock; None when tf2_msgs imports afterwards, else the failure."""
    started = time.monotonic()
    try:
        place.workdir.mkdir(parents=True, exist_ok=True)
        with exclusive(place.lock, log):
            if not force and available():            # another process built it while this one waited
                return None
            doing = "rebuilding it" if force else "not importable: building it once"
            log(f"tf2_msgs: {doing} into {place.prefix} (about 30 s; log {place.log})")
            with open(place.log, "w") as output:
                if install_requirements:
                    builder.install_requirements(output)

                def note(line: str) -> None:
                    output.write(line + "\n")
                    output.flush()
                build(place.prefix, place.workdir, log=note, output=output)
            if not available():
                raise RuntimeError(f"built, but `from tf2_msgs.msg import TFMessage` fails in {sys.executable}")
    except Exception as error:  # noqa: BLE001 - whatever fails: one line and the fallback, never a traceback
        reason = failure_reason(error)
        if isinstance(error, subprocess.CalledProcessError) and (detail := first_error(place.log)):
            reason = f"{reason}: {detail}"
        with contextlib.suppress(OSError):
            place.failed.write_text(reason + "\n")
        return f"build failed ({reason}; log {place.log})"
    with contextlib.suppress(OSError):
        place.failed.unlink()
    log(f"tf2_msgs: built into {place.prefix} in {time.monotonic() - started:.0f} s: /tf available")
    return None
