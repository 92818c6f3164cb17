"""Loaders for the KTH SLAM Summer School 2002 datasets (ACFR ute), numpy/scipy only.

Two datasets recorded by the Australian Centre for Field Robotics with the same
vehicle (see data/kth/README.md for provenance, formats and citation):

* Car Park: odometry (40 Hz), laser scans with reflectivity (~4.7 Hz), kinematic
  GPS (5 Hz) and 15 surveyed beacons (landmark ground truth).
* Victoria Park: dead reckoning (40 Hz), an intermittent GPS, and tree detections
  extracted from the laser (the raw laser file is not available).

Conventions returned by these loaders (used throughout the project):

* times in seconds (float64), on the dataset's own clock;
* observation bearings in the SENSOR frame: 0 = vehicle forward (sensor x axis),
  counter-clockwise positive, i.e. ``bearing = beam_angle - pi/2`` for the KTH beam
  angle (0..pi, pi/2 straight ahead);
* positions (GPS, beacons) in the local east/north GPS frame in metres; the GPS
  measures the laser point, which sits at (a, b) = (3.78, 0.5) m from base_link
  (rear-axle centre, x forward, y left).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

DATA_ENV_VAR = "ONLINE_EM_SLAM_DATA"
PACKAGE_NAME = "online_em_slam"

#: Time offset of tree_detections.dat: file time = original seconds - 20.967.
VICTORIA_TREE_TIME_OFFSET = 20.967
#: KTH laser: 361 beams over 0..180 deg, 0.5 deg apart; ranges >= 81.9 m = no return.
LASER_BEAMS = 361
LASER_ANGLE_INCREMENT = float(np.deg2rad(0.5))
#: Beam k (0-based) points at k/2 deg - 90 deg in the sensor frame.
LASER_ANGLE_MIN = -0.5 * np.pi
LASER_MAX_RANGE = 81.9


@dataclass(frozen=True)
class Vehicle:
    """ACFR ute geometry (metres).

    wheelbase L, encoder offset H (rear-left wheel encoder, left of the centre
    line), sensor (laser = GPS antenna) at ``sensor_x`` ahead of the rear axle
    and ``sensor_y`` to the left of the centre line.
    """

    wheelbase: float = 2.83
    encoder_offset: float = 0.76
    sensor_x: float = 3.78
    sensor_y: float = 0.5


VEHICLE = Vehicle()


@dataclass(frozen=True)
class OdometryStream:
    """Wheel-encoder speed v_e (m/s, rear-left wheel) and steering angle alpha (rad)."""

    times: np.ndarray
    speed: np.ndarray
    steering: np.ndarray

    def __len__(self) -> int:
        return len(self.times)


@dataclass(frozen=True)
class GpsTrack:
    """GPS fixes of the laser point, local east (x) / north (y) in metres."""

    times: np.ndarray
    x: np.ndarray
    y: np.ndarray

    def __len__(self) -> int:
        return len(self.times)

    @property
    def xy(self) -> np.ndarray:
        return np.column_stack([self.x, self.y])


@dataclass(frozen=True)
class LaserScans:
    """Laser scans (n, 361): ranges in metres (>= max_range = no return), raw intensities.

    ``angle_min`` / ``angle_increment`` give beam k at ``angle_min + k * angle_increment``
    in the sensor frame (0 = forward, CCW positive).
    """

    times: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray
    angle_min: float = LASER_ANGLE_MIN
    angle_increment: float = LASER_ANGLE_INCREMENT
    max_range: float = LASER_MAX_RANGE

    def __len__(self) -> int:
        return len(self.times)

    @property
    def beam_angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(self.ranges.shape[1])


@dataclass(frozen=True)
class CarPark:
    odometry: OdometryStream
    scans: LaserScans
    gps: GpsTrack
    beacons: np.ndarray          # (15, 2) surveyed beacon positions, GPS frame
    #: merged event list of the .mat file: (time, sensor 1=GPS 2=odometry 3=laser, 0-based index)
    event_times: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    event_sensors: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=int))
    event_indices: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=int))
    vehicle: Vehicle = VEHICLE


@dataclass(frozen=True)
class TreeScan:
    time: float
    range: np.ndarray
    bearing: np.ndarray
    diameter: np.ndarray


@dataclass(frozen=True)
class TreeDetections:
    """Tree detections grouped per scan (only scans with at least one detection).

    Flat per-detection arrays ``range`` (m, to the tree surface as given by the
    file), ``bearing`` (rad, SENSOR frame: 0 = forward, CCW positive) and
    ``diameter`` (m); detections of scan i are ``offsets[i]:offsets[i + 1]``;
    ``times[i]`` is the scan time on the dead-reckoning clock (offset applied).
    """

    times: np.ndarray
    offsets: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    diameter: np.ndarray

    def __len__(self) -> int:
        return len(self.times)

    @property
    def n_detections(self) -> int:
        return len(self.range)

    @property
    def centre_range(self) -> np.ndarray:
        """Range to the trunk centre: surface range + diameter / 2."""
        return self.range + 0.5 * self.diameter

    def scan(self, i: int) -> TreeScan:
        s = slice(int(self.offsets[i]), int(self.offsets[i + 1]))
        return TreeScan(float(self.times[i]), self.range[s], self.bearing[s], self.diameter[s])

    def __iter__(self) -> Iterator[TreeScan]:
        for i in range(len(self)):
            yield self.scan(i)


@dataclass(frozen=True)
class VictoriaPark:
    dr: OdometryStream
    gps: GpsTrack
    trees: TreeDetections
    vehicle: Vehicle = VEHICLE


# --------------------------------------------------------------------------- data dir

def _kth_dir(candidate: Path) -> Path | None:
    for d in (candidate, candidate / "kth", candidate / "data" / "kth"):
        if (d / "car_park").is_dir() or (d / "victoria_park").is_dir():
            return d
    return None


def candidate_data_dirs() -> list[Path]:
    """Places searched for the KTH data, in order."""
    out: list[Path] = []
    env = os.environ.get(DATA_ENV_VAR)
    if env:
        out.append(Path(env).expanduser())
    # Source tree / develop install: <repo>/online_em_slam/datasets/kth/datasets.py -> <repo>/data/kth
    out.append(Path(__file__).resolve().parents[3] / "data" / "kth")
    try:  # installed package: share/online_em_slam/data/kth
        from ament_index_python.packages import get_package_share_directory
        out.append(Path(get_package_share_directory(PACKAGE_NAME)) / "data" / "kth")
    except Exception:  # ament_index not importable or package not registered
        pass
    import sys
    out.append(Path(sys.prefix) / "share" / PACKAGE_NAME / "data" / "kth")
    return out


def default_data_dir() -> Path:
    """Directory holding ``car_park/`` and ``victoria_park/``.

    Searched: $ONLINE_EM_SLAM_DATA (the kth directory itself or a parent holding
    ``kth/``), the source tree's ``data/kth``, the installed share directory
    (ament_index, then ``sys.prefix/share/online_em_slam/data/kth``).
    """
    tried = candidate_data_dirs()
    for c in tried:
        found = _kth_dir(c)
        if found is not None:
            return found
    raise FileNotFoundError("KTH data not found; set $%s. Tried: %s"
                            % (DATA_ENV_VAR, ", ".join(str(t) for t in tried)))


def _resolve(data_dir, sub: str) -> Path:
    base = Path(data_dir) if data_dir is not None else default_data_dir()
    found = _kth_dir(base)
    base = found if found is not None else base
    path = base / sub
    if not path.is_dir():
        raise FileNotFoundError(f"{path} does not exist")
    return path


def _loadmat(path: Path) -> dict:
    from scipy.io import loadmat
    return loadmat(str(path), squeeze_me=True)


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1))


# --------------------------------------------------------------------------- loaders

def load_car_park(data_dir=None) -> CarPark:
    """Load ``car_park/data_set.mat`` and ``car_park/beac_juan3.mat``."""
    d = _resolve(data_dir, "car_park")
    m = _loadmat(d / "data_set.mat")
    odo = OdometryStream(_f64(m["Time_VS"]), _f64(m["Velocity"]), _f64(m["Steering"]))
    ranges = np.ascontiguousarray(np.asarray(m["Laser"], dtype=np.float64))
    intens = np.ascontiguousarray(np.asarray(m["Intensity"]))
    if ranges.shape != intens.shape or ranges.shape[1] != LASER_BEAMS:
        raise ValueError(f"unexpected laser shapes {ranges.shape} / {intens.shape}")
    scans = LaserScans(_f64(m["TimeLaser"]), ranges, intens)
    gps = GpsTrack(_f64(m["TimeGPS"]), _f64(m["GPSLon"]), _f64(m["GPSLat"]))
    beacons = np.asarray(_loadmat(d / "beac_juan3.mat")["estbeac"], dtype=np.float64).reshape(-1, 2)
    return CarPark(odo, scans, gps, beacons,
                   event_times=_f64(m["Time"]),
                   event_sensors=np.asarray(m["Sensor"], dtype=np.int64).reshape(-1),
                   event_indices=np.asarray(m["Index"], dtype=np.int64).reshape(-1) - 1)


def load_tree_detections(path, time_offset: float = VICTORIA_TREE_TIME_OFFSET) -> TreeDetections:
    """Parse ``tree_detections.dat`` (t, range, bearing, diameter per row).

    ``time_offset`` is added to t (rounded to the file's millisecond resolution);
    bearings are converted from the KTH beam convention (pi/2 ahead) to the sensor
    frame (0 ahead).
    """
    rows = np.loadtxt(str(path), dtype=np.float64, ndmin=2)
    if rows.shape[1] != 4:
        raise ValueError(f"{path}: expected 4 columns, got {rows.shape[1]}")
    t = np.round(rows[:, 0] + time_offset, 6)
    order = np.argsort(t, kind="stable")
    rows, t = rows[order], t[order]
    times, starts = np.unique(t, return_index=True)
    offsets = np.append(starts, len(t)).astype(np.int64)
    return TreeDetections(times, offsets, np.ascontiguousarray(rows[:, 1]),
                          np.ascontiguousarray(rows[:, 2] - 0.5 * np.pi),
                          np.ascontiguousarray(rows[:, 3]))


def load_victoria_park(data_dir=None) -> VictoriaPark:
    """Load ``aa3_dr.mat``, ``aa3_gpsx.mat`` (times ms -> s) and ``tree_detections.dat``."""
    d = _resolve(data_dir, "victoria_park")
    dr = _loadmat(d / "aa3_dr.mat")
    gps = _loadmat(d / "aa3_gpsx.mat")
    return VictoriaPark(
        OdometryStream(_f64(dr["time"]) / 1000.0, _f64(dr["speed"]), _f64(dr["steering"])),
        GpsTrack(_f64(gps["timeGps"]) / 1000.0, _f64(gps["Lo_m"]), _f64(gps["La_m"])),
        load_tree_detections(d / "tree_detections.dat"),
    )


DATASETS = {"car_park": load_car_park, "victoria_park": load_victoria_park}


def load(name: str, data_dir=None):
    try:
        return DATASETS[name](data_dir)
    except KeyError:
        raise ValueError(f"unknown dataset {name!r}; choose from {sorted(DATASETS)}") from None
