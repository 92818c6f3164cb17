"""ROS 2 node: reflective beacons from a LaserScan with intensities -> landmark observations.

Subscribes ``scan`` (sensor_msgs/LaserScan), publishes ``landmark_observations``
(sensor_msgs/PointCloud2 in the scan's frame, same header) with the project's
observation layout (cloud.OBSERVATION_FIELDS): x, y, z, range, bearing, id (-1),
range_std, bearing_std.  Bearings follow the scan's own angles
(angle_min + k * angle_increment), i.e. the sensor frame.

Parameters: min_intensity (1.0), max_range (0 = the scan's range_max),
beacon_radius (0.0 m), max_range_jump (1.0 m; <= 0 disables splitting),
range_std / bearing_std (0.0 = "use the configured noise"),
input_reliability ("best_effort" | "reliable"), input_depth (50).
"""
from __future__ import annotations

import sys

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan, PointCloud2, PointField

from ...messages.cloud import OBSERVATION_FIELDS, build_message
from .beacons import extract_beacons, observation_columns


def cloud_message(header, columns: dict, layout=OBSERVATION_FIELDS) -> PointCloud2:
    """An rclpy PointCloud2 (height 1) from columns with the given layout."""
    return build_message(PointCloud2, PointField, header, columns, layout)


class BeaconNode(Node):
    def __init__(self, **kwargs):
        super().__init__("beacon_extractor", **kwargs)
        self.min_intensity = float(self.declare_parameter("min_intensity", 1.0).value)
        self.max_range = float(self.declare_parameter("max_range", 0.0).value)
        self.beacon_radius = float(self.declare_parameter("beacon_radius", 0.0).value)
        jump = float(self.declare_parameter("max_range_jump", 1.0).value)
        self.max_range_jump = jump if jump > 0 else None
        self.range_std = float(self.declare_parameter("range_std", 0.0).value)
        self.bearing_std = float(self.declare_parameter("bearing_std", 0.0).value)
        reliability = str(self.declare_parameter("input_reliability", "best_effort").value)
        depth = int(self.declare_parameter("input_depth", 50).value)
        qos_in = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(depth, 1),
                            reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable"
                            else ReliabilityPolicy.BEST_EFFORT)
        qos_out = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(depth, 1),
                             reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(PointCloud2, "landmark_observations", qos_out)
        self.sub = self.create_subscription(LaserScan, "scan", self.on_scan, qos_in)
        self.n_scans = 0
        self.n_detections = 0

    def on_scan(self, scan: LaserScan) -> None:
        ranges = np.asarray(scan.ranges, dtype=np.float64)
        intensities = np.asarray(scan.intensities, dtype=np.float64)
        if intensities.size != ranges.size:   # no intensities: nothing is reflective
            intensities = np.zeros_like(ranges)
        max_range = self.max_range if self.max_range > 0 else float(scan.range_max)
        # LaserScan ranges equal to range_max are valid; extract_beacons excludes the limit itself.
        beacons = extract_beacons(ranges, intensities, scan.angle_min, scan.angle_increment,
                                  min_intensity=self.min_intensity,
                                  max_range=np.nextafter(max_range, np.inf),
                                  min_range=max(float(scan.range_min), 0.0),
                                  beacon_radius=self.beacon_radius, max_range_jump=self.max_range_jump)
        cols = observation_columns(beacons.range, beacons.bearing,
                                   range_std=self.range_std, bearing_std=self.bearing_std)
        self.pub.publish(cloud_message(scan.header, cols))
        self.n_scans += 1
        self.n_detections += len(beacons)


def main(argv=None) -> int:
    rclpy.init(args=argv if argv is not None else sys.argv)
    node = BeaconNode()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.get_logger().info(f"{node.n_scans} scans, {node.n_detections} beacons")
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
