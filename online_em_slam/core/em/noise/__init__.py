"""The noise learned online by the same EM: the learner (learner.py) and its statistics
(observation.py, range_fit.py, serial_correlation.py, motion_noise.py, motion_gains.py)
with their stochastic-approximation averages (averages.py)."""
