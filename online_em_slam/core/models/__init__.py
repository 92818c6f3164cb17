"""The HMM's models: motion (pose transition), range-bearing observation, angles."""
