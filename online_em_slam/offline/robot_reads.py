"""Robot-to-robot reads as factors of a fleet's batch problem (offline/fleet_batch.py).

MRCLAM's robots read each other's barcodes as they read the landmarks' (range, bearing from
the reading robot's centre; datasets/mrclam/dataset.py ``load_robot_reads``, given to the batch
by datasets/mrclam/fleet_batch.py).  A read at time t of robot b by robot a is a bearing-range
factor between a's pose and b's pose at t, GTSAM's BearingRangeFactorPose2 (a custom factor with
a sensor lever arm):

* the barcode is taken to sit on the read robot's centre, the point its ground-truth pose
  gives: the MRCLAM README does not say where it sits, and the reads placed from the Vicon
  poses land within 1 cm of the read robot's centre (median over Dataset 1's 2530 reads in
  its first 600 s, about which they spread by 8 cm);
* both robots get a pose variable at t (:class:`.extra_poses.ExtraPoses`: the motion into it
  compounded from the inputs as a scan's is), so no read waits for a scan;
* R is the landmark reads' (the reading robot's noise, :func:`..core.models.observation.noise_covariance`
  under ``information_noise``): Gaussian, as every factor of the batch.  The batch has no
  robust kernel, so a gross misread is gated instead: after a first solve with every read, the
  reads whose squared Mahalanobis distance at that optimum exceeds the gate (chi-square, 2
  degrees of freedom, :data:`DEFAULT_READ_GATE`) are left out and the problem solved again.
  Every robot's sensor sits where the first robot's configuration puts it.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.models.observation import information_noise, inv_det_2x2, noise_covariance
from ..baselines.gtsam_batch import symbols
from .observation_factors import lever_arm_measurement

#: Squared Mahalanobis distance above which a read is a misread: chi-square 2 dof, 0.999.
DEFAULT_READ_GATE = 13.8


@dataclass
class FleetReads:
    """The reads between robots of one fleet, n of them: ``stamps`` (n,) bag stamps, ``observer`` and
    ``observed`` (n,) robot indices in the fleet's order, ``y`` (n, 2) range, bearing;
    ``not_in_the_bag``: reads of the dataset not among them, by reason."""

    stamps: np.ndarray
    observer: np.ndarray
    observed: np.ndarray
    y: np.ndarray
    not_in_the_bag: Counter = field(default_factory=Counter)

    def __len__(self) -> int:
        return len(self.stamps)

    def stamps_of(self, robot: int) -> np.ndarray:
        """The stamps at which robot index ``robot`` reads or is read (its extra pose variables)."""
        return self.stamps[(self.observer == robot) | (self.observed == robot)]


def fleet_reads(stamps, observers, observed, y, names: list[str], spans: list[tuple[float, float]]) -> FleetReads:
    """Reads at bag ``stamps`` (n,) of robot ``observed[i]`` by robot ``observers[i]`` (robot names, n
    each), ``y`` (n, 2) range, bearing: those between the fleet's robots ``names`` within both robots'
    input ``spans`` (first, last stamp in the bag, one per name)."""
    index = {name: i for i, name in enumerate(names)}
    stamps = np.asarray(stamps, dtype=np.float64)
    a = np.array([index.get(r, -1) for r in observers], dtype=np.int64)
    b = np.array([index.get(r, -1) for r in observed], dtype=np.int64)
    in_fleet = (a >= 0) & (b >= 0)
    lo, hi = np.array([s[0] for s in spans]), np.array([s[1] for s in spans])
    inside = in_fleet & (stamps >= lo[a]) & (stamps <= hi[a]) & (stamps >= lo[b]) & (stamps <= hi[b])
    outside = Counter(robot_not_in_fleet=int(np.count_nonzero(~in_fleet)),
                      outside_the_bag_span=int(np.count_nonzero(in_fleet & ~inside)))
    return FleetReads(stamps[inside], a[inside], b[inside], np.asarray(y, dtype=np.float64).reshape(-1, 2)[inside],
                      outside)


def odometry_spans(inputs) -> list[tuple[float, float]]:
    """(first, last) odometry stamp of each robot of a fleet bag's inputs (FleetInputs): the span a
    read must fall in to have both robots' poses ((inf, -inf) for a robot without odometry)."""
    return [(float(r.odom_times[0]), float(r.odom_times[-1])) if len(r.odom_times) else (np.inf, -np.inf)
            for r in inputs.robots]


@dataclass
class ReadFactors:
    """The reads as factors of the joint problem, n of them: ``observer``, ``observed`` (n,) pose
    variables, ``y`` (n, 2) range, bearing, ``R`` (n, 2, 2) in (range, bearing) order; ``read`` (n,)
    the index of each in its :class:`FleetReads`; ``left_out``: reads without a factor, by reason."""

    observer: np.ndarray
    observed: np.ndarray
    y: np.ndarray
    R: np.ndarray
    read: np.ndarray
    left_out: Counter = field(default_factory=Counter)

    def __len__(self) -> int:
        return len(self.read)

    def subset(self, keep: np.ndarray, reason: str) -> "ReadFactors":
        """The factors where ``keep`` (n,) holds; the others counted under ``reason``."""
        left_out = self.left_out + Counter({reason: int(np.count_nonzero(~keep))})     # + drops zero counts
        return ReadFactors(self.observer[keep], self.observed[keep], self.y[keep], self.R[keep], self.read[keep],
                           left_out)


def pose_variables(stamps: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Index (n,) of each ``wanted`` stamp in a robot's increasing pose variable ``stamps`` (T,), -1
    where none (the extra variables sit at exactly the read's stamp)."""
    if not len(stamps):
        return np.full(len(wanted), -1)
    i = np.searchsorted(stamps, wanted).clip(0, len(stamps) - 1)
    return np.where(stamps[i] == wanted, i, -1)


def read_factors(reads: FleetReads, problems: list, chain_starts, configs: list) -> ReadFactors:
    """Each read's two pose variables in the joint problem (robot r's problem ``problems[r]`` from
    variable ``chain_starts[r]`` on) and its R, the observing robot's landmark-read noise."""
    a, b = np.full(len(reads), -1), np.full(len(reads), -1)
    for r, (problem, start) in enumerate(zip(problems, chain_starts)):
        for ends, robots in ((a, reads.observer), (b, reads.observed)):
            mine = robots == r
            found = pose_variables(problem.stamps, reads.stamps[mine])
            ends[mine] = np.where(found >= 0, found + start, -1)
    R = np.zeros((len(reads), 2, 2))
    for r, config in enumerate(configs):
        mine = reads.observer == r
        R[mine] = noise_covariance(information_noise(config.noise), reads.y[mine, 0])
    factors = ReadFactors(a, b, reads.y, R, np.arange(len(reads)))
    return factors.subset((a >= 0) & (b >= 0), "no_pose_variable")


def read_measurement(observer_pose, observed_pose, offset=(0.0, 0.0, 0.0)):
    """h = (range, bearing) (2,) of the observed robot's centre from the observer's sensor at
    ``offset`` (x, y, yaw), and its Jacobians (2, 3) in each pose's tangent space (X Exp(xi))."""
    h, H_a, H_point = lever_arm_measurement(observer_pose, observed_pose[:2], offset)
    c, s = np.cos(observed_pose[2]), np.sin(observed_pose[2])
    # The observed centre moves by R(theta) xi_t: its heading does not move it.
    H_b = np.column_stack([H_point @ np.array([[c, -s], [s, c]]), np.zeros(2)])
    return h, H_a, H_b


def squared_distances(poses: np.ndarray, factors: ReadFactors, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Squared Mahalanobis distance (n,) of each read from the prediction at ``poses`` (T, 3)."""
    residuals = np.array([_residual(poses[a], poses[b], y, offset)
                          for a, b, y in zip(factors.observer, factors.observed, factors.y)]).reshape(-1, 2)
    inverse, _ = inv_det_2x2(factors.R)
    return np.einsum("ni,nij,nj->n", residuals, inverse, residuals)


def _residual(observer_pose, observed_pose, y, offset) -> np.ndarray:
    h = read_measurement(observer_pose, observed_pose, offset)[0]
    return np.array([h[0] - y[0], wrap_angle(h[1] - y[1])])


def gtsam_factors(gtsam, factors: ReadFactors, sensor) -> list:
    """One GTSAM factor per read: BearingRangeFactorPose2 (bearing first) for a sensor on the robot's
    centre, a custom factor with the lever arm otherwise."""
    X = symbols(gtsam)[0]
    offset = (sensor.offset_x, sensor.offset_y, sensor.offset_yaw)
    lever = sensor.offset_x != 0.0 or sensor.offset_y != 0.0
    out = []
    for a, b, y, R in zip(factors.observer, factors.observed, factors.y, factors.R):
        noise = gtsam.noiseModel.Gaussian.Covariance(R if lever else R[::-1, ::-1].copy())
        if lever:
            out.append(_lever_arm_read(gtsam, noise, X(int(a)), X(int(b)), y, offset))
            continue
        bearing = gtsam.Rot2(float(wrap_angle(y[1] + sensor.offset_yaw)))
        out.append(gtsam.BearingRangeFactorPose2(X(int(a)), X(int(b)), bearing, float(y[0]), noise))
    return out


def _lever_arm_read(gtsam, noise, observer_key, observed_key, y, offset):
    y = np.array(y, dtype=float)

    def error(this, values, jacobians):
        a, b = (values.atPose2(k) for k in this.keys())
        h, H_a, H_b = read_measurement((a.x(), a.y(), a.theta()), (b.x(), b.y(), b.theta()), offset)
        if jacobians is not None:
            jacobians[0], jacobians[1] = H_a, H_b
        return np.array([h[0] - y[0], wrap_angle(h[1] - y[1])])

    return gtsam.CustomFactor(noise, [observer_key, observed_key], error)
