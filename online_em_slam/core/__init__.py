"""ROS-free estimation core: particle online EM SLAM and its building blocks."""
from .config import (AssociationConfig, EMConfig, FilterConfig, MotionConfig,
                     ObservationNoiseConfig, SensorConfig, SlamConfig)
from .filter.slam import OnlineEMSlam
from .fleet.slam import FleetSlam
from .types import LandmarkMap, Observations, PoseEstimate, StepReport

__all__ = ["AssociationConfig", "EMConfig", "FilterConfig", "MotionConfig", "ObservationNoiseConfig",
           "SensorConfig", "SlamConfig", "OnlineEMSlam", "FleetSlam", "LandmarkMap", "Observations",
           "PoseEstimate", "StepReport"]
