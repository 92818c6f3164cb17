"""The input path, ROS-free: stamp checks, loss detection, the stamp-ordered merge
of the input streams and the feeding of an estimator, in one :class:`InputPipeline`
shared by the ROS node (:mod:`online_em_slam.ros.node`) and the offline runner
(:mod:`online_em_slam.offline.runner`).
"""
from .feeder import Fed, Feeder
from .input_path import InputPath, Pushed
from .input_pipeline import InputPipeline, merged_streams
from .inputs import CONTROL, KIND_NAME, MOTION_KINDS, OBSERVATIONS, ODOMETRY, TIE_ORDER, Input, order_key
from .load import LoadMonitor
from .sequencer import Sequencer
from .stamp_guard import StampGuard

__all__ = ["CONTROL", "Fed", "Feeder", "Input", "InputPath", "InputPipeline", "KIND_NAME", "LoadMonitor",
           "MOTION_KINDS", "OBSERVATIONS", "ODOMETRY", "Pushed", "Sequencer", "StampGuard", "TIE_ORDER",
           "merged_streams", "order_key"]
