"""The input path, ROS-free: stamp checks, loss detection, the stamp-ordered merge
of the input streams and the feeding of an estimator, shared by the ROS node
(:mod:`online_em_slam.ros.node`) and the offline runner (:mod:`online_em_slam.cli`).
"""
from .feeder import Fed, Feeder
from .input_path import InputPath, Pushed
from .inputs import CONTROL, KIND_NAME, MOTION_KINDS, OBSERVATIONS, ODOMETRY, Input
from .load import LoadMonitor
from .sequencer import Sequencer
from .stamp_guard import StampGuard

__all__ = ["CONTROL", "Fed", "Feeder", "Input", "InputPath", "KIND_NAME", "LoadMonitor", "MOTION_KINDS",
           "OBSERVATIONS", "ODOMETRY", "Pushed", "Sequencer", "StampGuard"]
