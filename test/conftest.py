"""ROS environment for in-process rclpy tests (must be set before rclpy is imported)."""
import os

# All test nodes live in one process and context: no discovery outside it, so
# concurrent test runs on this host cannot see each other's topics.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
