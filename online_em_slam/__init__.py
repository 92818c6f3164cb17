"""online_em_slam: landmark SLAM by particle online Expectation-Maximization."""
__version__ = "0.1.0"
