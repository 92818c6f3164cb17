"""online_em_slam: landmark SLAM by particle online Expectation-Maximization."""
import os as _os

# The per-step matrices are small (N = 100 particles): BLAS threads only add
# contention with the ROS executor and with other processes, and made the
# Victoria Park run slower.  Applies when numpy is first imported through this
# package; an explicit setting in the environment wins.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")

__version__ = "0.1.0"
