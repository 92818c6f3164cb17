"""UTIAS MRCLAM dataset: loader (numpy only) and ROS 2 bag converter (rosbags, imported lazily)."""
from .dataset import DROP_REASONS, ROBOTS, MrclamRun, load_mrclam

__all__ = ["DROP_REASONS", "ROBOTS", "MrclamRun", "load_mrclam"]
