"""The EM part: the data one filter step hands over, the sufficient statistics and
smoothers, the M-step variants (complete-data, observed-information) and the noise
learner."""
