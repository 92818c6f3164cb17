#!/usr/bin/env python3
"""Build the wheels-only tf2_msgs (TFMessage only) into this venv; run by ``make install``.

    .venv/bin/python tools/build_tf2_msgs.py [--force]

Installs ``requirements-tf2.txt`` (ament_cmake, rosidl generators, catkin_pkg,
ninja; cmake too when the machine has none), builds ``tools/tf2_msgs`` with
:mod:`online_em_slam.ros.tf` into ``sys.prefix`` and checks that a fresh
interpreter imports ``tf2_msgs.msg``.  It never fails the install: on any
error it prints one warning line (the log file has the details) and exits 0;
the node then keeps sending map -> odom on ``~/map_to_odom``.  Does nothing
when tf2_msgs is already importable (``--force`` rebuilds).  Set
``ONLINE_EM_SLAM_NO_TF2_MSGS=1`` to skip it.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REQUIREMENTS = ROOT / "requirements-tf2.txt"
IMPORT_CHECK = "from tf2_msgs.msg import TFMessage"


def importable() -> bool:
    """In a fresh interpreter: the wheels' re-exec sets LD_LIBRARY_PATH at start."""
    return subprocess.run([sys.executable, "-c", IMPORT_CHECK], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL, timeout=120).returncode == 0


def pip_install(args: list[str], log) -> None:
    log.write(f"$ pip install {' '.join(args)}\n")
    log.flush()
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", *args], stdout=log, stderr=subprocess.STDOUT,
                   check=True, timeout=600)


def build(prefix: Path, log) -> None:
    pip_install(["-r", str(REQUIREMENTS)], log)
    if shutil.which("cmake") is None and not (prefix / "bin" / "cmake").exists():
        pip_install(["cmake"], log)
    sys.path.insert(0, str(ROOT))
    from online_em_slam.ros import tf  # noqa: PLC0415 (after the path is set)

    def note(line: str) -> None:
        log.write(line + "\n")
        log.flush()
    tf.build(prefix, prefix / "build" / "tf2_msgs", log=note, output=log)
    if not importable():
        raise RuntimeError(f"built, but `{IMPORT_CHECK}` fails in {sys.executable}")


def main(argv: list[str]) -> int:
    prefix = Path(sys.prefix).resolve()
    if os.environ.get("ONLINE_EM_SLAM_NO_TF2_MSGS"):
        print("tf2_msgs: skipped (ONLINE_EM_SLAM_NO_TF2_MSGS): map -> odom goes to ~/map_to_odom")
        return 0
    if "--force" not in argv and importable():
        print("tf2_msgs: already importable: the node publishes map -> odom on /tf")
        return 0
    log_path = prefix / "build" / "tf2_msgs.log"
    started = time.monotonic()
    try:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "w") as log:
            build(prefix, log)
    except Exception as error:  # noqa: BLE001 - the install must go on whatever fails here
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"warning: tf2_msgs not built ({reason}; see {log_path}): "
              "the node sends map -> odom on ~/map_to_odom instead of /tf")
        return 0
    print(f"tf2_msgs: built into {prefix} in {time.monotonic() - started:.0f} s: "
          "the node publishes map -> odom on /tf")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
