"""Baseline estimators with the public API of :class:`online_em_slam.core.OnlineEMSlam`.

- :class:`EkfSlam`    joint-state EKF-SLAM;
- :class:`FastSlam2`  FastSLAM 2.0 (Montemerlo et al. 2003), vectorised over particles;
- :class:`MarginalSlam` marginal-SLAM (Martinez-Cantin 2008): the online-EM particle filter
  with the map by recursive maximum likelihood (:class:`RecursiveMLMapUpdate`);
- :func:`batch_estimate` (module ``gtsam_batch``) batch maximum likelihood with GTSAM,
  an optional dependency imported only when called.
"""
from .ekf_slam import EkfSlam
from .fastslam2 import FastSlam2
from .gtsam_batch import BatchResult, batch_estimate, dead_reckoning
from .marginal_slam import MarginalSlam, RecursiveMLMapUpdate

__all__ = ["EkfSlam", "FastSlam2", "MarginalSlam", "RecursiveMLMapUpdate", "BatchResult", "batch_estimate",
           "dead_reckoning"]
