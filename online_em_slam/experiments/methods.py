"""The methods the seed-scenario benchmark runs, and the scores it reports."""

# online_em / boem: the default observed-information M-step (no smoother needed);
# *_complete*: the seed's complete-data M-step with each smoother.
ONLINE_METHODS = {
    "online_em": dict(m_step="observed", smoother="forward", algorithm="online"),
    "boem": dict(m_step="observed", smoother="forward", algorithm="block"),
    "online_em_complete_forward": dict(m_step="complete", smoother="forward", algorithm="online"),
    "online_em_complete_paris": dict(m_step="complete", smoother="paris", algorithm="online"),
    "online_em_complete_ancestry": dict(m_step="complete", smoother="ancestry", algorithm="online"),
    "boem_complete": dict(m_step="complete", smoother="forward", algorithm="block"),
    "boem_averaged_complete": dict(m_step="complete", smoother="forward", algorithm="block_averaged"),
}
# marginal_slam: the online-EM particle filter with the map by recursive ML (baselines/marginal_slam.py);
# it shares the online methods' filter, so --set applies to it too.
BASELINES = ("fastslam2", "ekf_slam", "marginal_slam")
ALL_METHODS = tuple(ONLINE_METHODS) + BASELINES + ("gtsam_batch",)
# Per-run scores summarised (mean, se) and compared pairwise.
SCORES = ("landmark_rmse", "shape_error", "frame_error", "pose_rmse", "mean_step_ms")
