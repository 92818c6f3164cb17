"""Baseline estimators with the public API of :class:`online_em_slam.core.OnlineEMSlam`.

- :class:`EkfSlam`    joint-state EKF-SLAM;
- :class:`FastSlam2`  FastSLAM 2.0 (Montemerlo et al. 2003), vectorised over particles;
- :func:`batch_estimate` (module ``gtsam_batch``) batch maximum likelihood with GTSAM,
  an optional dependency imported only when called.
"""
from .ekf_slam import EkfSlam
from .fastslam2 import FastSlam2
from .gtsam_batch import BatchResult, batch_estimate, dead_reckoning

__all__ = ["EkfSlam", "FastSlam2", "BatchResult", "batch_estimate", "dead_reckoning"]
