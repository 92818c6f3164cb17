"""The sensor pose from TF (tf2_ros when importable) and the frame checks of the inputs.

``python -m online_em_slam.ros.tf build|check`` is kept as another name of
``online-em-slam-tf2-msgs`` (:mod:`online_em_slam.messages.tf2_build`), which builds
a wire-compatible tf2_msgs into a PyPI-wheels environment.
"""
from __future__ import annotations

import dataclasses
import math
import sys
from collections import Counter

#: A TF sensor pose this close to the parameters' mount leaves the observations as they are.
SAME_MOUNT_TOLERANCE = 1e-6


def reexpress(observations, mount):
    """Observations in a frame at ``mount`` = (x, y, yaw) in the configured sensor frame,
    re-expressed in the configured sensor frame (range_std / bearing_std kept)."""
    x, y, yaw = mount
    if max(abs(x), abs(y), abs(math.remainder(yaw, math.tau))) <= SAME_MOUNT_TOLERANCE:
        return observations
    import numpy as np  # noqa: PLC0415 (only when a mount is to be undone)
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
    """``python -m online_em_slam.ros.tf``: the ``online-em-slam-tf2-msgs`` command."""
    from ..messages.tf2_build.cli import main as tf2_msgs_main  # noqa: PLC0415
    return tf2_msgs_main(argv)


if __name__ == "__main__":
    sys.exit(main())
