"""UTIAS MRCLAM dataset: loader (numpy only) and ROS 2 bag converter (rosbags, imported lazily)."""
from .dataset import DROP_REASONS, ROBOTS, MrclamRun, RobotReads, load_mrclam, load_robot_reads

__all__ = ["DROP_REASONS", "ROBOTS", "MrclamRun", "RobotReads", "load_mrclam", "load_robot_reads"]
