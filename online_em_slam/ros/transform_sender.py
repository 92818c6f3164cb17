"""map -> odom through the best available channel: tf2_ros, tf2_msgs on /tf, or ~/map_to_odom."""
from __future__ import annotations

from geometry_msgs.msg import TransformStamped
from rclpy.qos import QoSProfile


class TransformSender:
    """Sends map -> odom; ``kind`` says through which channel (logged at start-up)."""

    def __init__(self, node) -> None:
        self.kind = "none"
        try:
            from tf2_ros import TransformBroadcaster  # noqa: PLC0415 (optional at run time)
            self._broadcaster = TransformBroadcaster(node)
            self.kind = "tf2_ros.TransformBroadcaster on /tf"
            self._send = self._broadcaster.sendTransform
            return
        except ImportError:
            pass
        try:
            from tf2_msgs.msg import TFMessage  # noqa: PLC0415
            publisher = node.create_publisher(TFMessage, "/tf", QoSProfile(depth=100))
            self.kind = "tf2_msgs/TFMessage on /tf"
            self._send = lambda t: publisher.publish(TFMessage(transforms=[t]))
            return
        except ImportError:
            pass
        publisher = node.create_publisher(TransformStamped, "~/map_to_odom", QoSProfile(depth=10))
        self.kind = ("geometry_msgs/TransformStamped on ~/map_to_odom (tf2_ros and tf2_msgs not importable; "
                     "online-em-slam-tf2-msgs build builds tf2_msgs)")
        self._send = publisher.publish

    def send(self, transform: TransformStamped) -> None:
        self._send(transform)
