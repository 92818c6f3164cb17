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
import dataclasses
import math
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from collections import Counter
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
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return False
    return TFMessage is not None


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


#: A TF sensor pose this close to the parameters' mount leaves the observations as they are.
SAME_MOUNT_TOLERANCE = 1e-6


def reexpress(observations, mount):
    """Observations in a frame at ``mount`` = (x, y, yaw) in the configured sensor frame,
    re-expressed in the configured sensor frame (range_std / bearing_std kept)."""
    x, y, yaw = mount
    if max(abs(x), abs(y), abs(math.remainder(yaw, math.tau))) <= SAME_MOUNT_TOLERANCE:
        return observations
    import numpy as np  # noqa: PLC0415 (tf.py builds tf2_msgs without the node's dependencies)
    r, b = observations.ranges, observations.bearings
    px = x + r * np.cos(b + yaw)
    py = y + r * np.sin(b + yaw)
    return dataclasses.replace(observations, ranges=np.hypot(px, py), bearings=np.arctan2(py, px))


class SensorFrames:
    """Frame ids of the inputs, and the sensor pose from TF when tf2_ros is importable.

    An observation cloud's ranges and bearings are read in its ``header.frame_id``.
    With tf2_ros (a real Jazzy install), the pose of that frame in ``base_frame``
    is looked up (at the cloud's stamp, else the latest) and the observations
    are re-expressed in the sensor frame the estimator uses (``sensor.offset_*``),
    so TF, not the parameters, places the sensor; a cloud in ``base_frame`` is
    placed this way too.  When the lookup fails (or without tf2_ros) the cloud
    is read as in the sensor frame of the parameters.  A cloud in a frame that
    is neither the configured ``sensor_frame`` (or ``base_frame``) nor resolvable
    through TF, or in ``map_frame``/``odom_frame``, is used but counted
    (``unexpected_frame.<frame>``); so is a cloud without a frame id, and, with
    ``sensor_frame`` unset, a cloud in another frame than the first cloud's (the
    sensor frame then).  An odometry message whose ``child_frame_id`` is not
    ``base_frame`` is counted (``unexpected_child_frame.<frame>``), one whose
    ``header.frame_id`` is not ``odom_frame`` too (``unexpected_odom_frame.<frame>``);
    each frame is warned about once.
    """

    def __init__(self, node, warn=None) -> None:
        self._warn = warn or node.get_logger().warning
        self._buffer = None
        try:
            import tf2_ros  # noqa: PLC0415 (optional: a real Jazzy install)
            self._buffer = tf2_ros.Buffer()
            self._listener = tf2_ros.TransformListener(self._buffer, node, spin_thread=False)
        except ImportError:
            self._buffer = None
        self.unexpected_frames: Counter = Counter()          # observation clouds by frame id
        self.unexpected_child_frames: Counter = Counter()    # odometry by child_frame_id
        self.unexpected_odom_frames: Counter = Counter()     # odometry by header.frame_id
        self.first_cloud_frame: str | None = None            # the sensor frame when sensor_frame is unset
        self.placed_by_tf = 0                                # clouds whose sensor pose came from TF
        self.tf_failures = 0                                 # lookups that fell back to the parameters
        self._warned: set = set()

    @property
    def uses_tf(self) -> bool:
        return self._buffer is not None

    def _warn_once(self, key, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self._warn(message)

    def check_odometry(self, child_frame_id: str, settings, frame_id: str | None = None) -> None:
        if frame_id is not None and frame_id != settings.odom_frame:
            self.unexpected_odom_frames[frame_id] += 1
            self._warn_once(("odom", frame_id),
                            f"odometry in frame {frame_id!r}, not odom_frame {settings.odom_frame!r}: used as "
                            "odometry, counted as unexpected_odom_frame (warned once)")
        if child_frame_id == settings.base_frame:
            return
        self.unexpected_child_frames[child_frame_id] += 1
        self._warn_once(("child", child_frame_id),
                        f"odometry child_frame_id {child_frame_id!r} is not base_frame {settings.base_frame!r}: "
                        "used as the base pose, counted as unexpected_child_frame (warned once)")

    def lookup(self, frame: str, stamp: float, settings):
        """(x, y, yaw) of ``frame`` in ``base_frame`` from TF, or None."""
        if self._buffer is None or not frame:
            return None
        from rclpy.time import Time  # noqa: PLC0415
        for when in (Time(nanoseconds=max(int(round(stamp * 1e9)), 0)), Time()):
            try:
                t = self._buffer.lookup_transform(settings.base_frame, frame, when).transform
            except Exception:  # noqa: BLE001 - tf2 errors, bad frame names: the parameters' pose instead
                continue
            from ..messages.quaternion import quaternion_to_yaw  # noqa: PLC0415
            pose = (float(t.translation.x), float(t.translation.y), quaternion_to_yaw(t.rotation))
            if all(math.isfinite(v) for v in pose):
                return pose
        self.tf_failures += 1
        return None

    def observations(self, frame: str, stamp: float, observations, settings, sensor):
        """The cloud's observations in the estimator's sensor frame; counts unexpected frames."""
        if frame in (settings.map_frame, settings.odom_frame, ""):
            self._unexpected(frame, settings)
            return observations
        if self.first_cloud_frame is None:
            self.first_cloud_frame = frame
        pose = self.lookup(frame, stamp, settings)
        if pose is None:
            sensor_frame = settings.sensor_frame or self.first_cloud_frame
            if frame not in (sensor_frame, settings.base_frame):
                self._unexpected(frame, settings)
            return observations
        self.placed_by_tf += 1
        # The cloud frame's pose in the parameters' sensor frame: T(base<-sensor)^-1 * T(base<-cloud).
        c, s = math.cos(sensor.offset_yaw), math.sin(sensor.offset_yaw)
        dx, dy = pose[0] - sensor.offset_x, pose[1] - sensor.offset_y
        mount = (c * dx + s * dy, -s * dx + c * dy, pose[2] - sensor.offset_yaw)
        if max(abs(mount[0]), abs(mount[1]), abs(math.remainder(mount[2], math.tau))) > SAME_MOUNT_TOLERANCE:
            self._warn_once(("mount", frame),
                            f"sensor pose of {frame!r} from TF ({pose[0]:.3f}, {pose[1]:.3f}, {pose[2]:.3f}) "
                            f"differs from sensor.offset_* ({sensor.offset_x:.3f}, {sensor.offset_y:.3f}, "
                            f"{sensor.offset_yaw:.3f}): TF is used (warned once)")
        return reexpress(observations, mount)

    def _unexpected(self, frame: str, settings) -> None:
        self.unexpected_frames[frame] += 1
        through = ", nor resolvable through TF" if self.uses_tf else ""
        self._warn_once(("cloud", frame),
                        f"observation cloud in frame {frame!r}, not "
                        f"{settings.sensor_frame or self.first_cloud_frame or 'a sensor frame'!r}"
                        f"{through}: read as sensor-relative, counted as unexpected_frame (warned once)")

    def diagnostics(self) -> dict:
        values = {f"unexpected_frame.{frame or '(empty)'}": count
                  for frame, count in sorted(self.unexpected_frames.items())}
        values.update({f"unexpected_child_frame.{frame or '(empty)'}": count
                       for frame, count in sorted(self.unexpected_child_frames.items())})
        values.update({f"unexpected_odom_frame.{frame or '(empty)'}": count
                       for frame, count in sorted(self.unexpected_odom_frames.items())})
        if self.uses_tf:
            values.update({"sensor_pose_from_tf": self.placed_by_tf, "sensor_pose_tf_failures": self.tf_failures})
        return values


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
