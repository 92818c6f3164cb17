"""The simulator, the seed-scenario benchmark and the demo."""
