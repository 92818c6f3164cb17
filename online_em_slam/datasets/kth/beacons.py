"""Reflective-beacon extraction from a laser scan with intensities (numpy only).

The Car Park beacons are poles wrapped in reflective tape; the laser marks a
beam that hits one with a non-zero intensity.  A beacon is a run of consecutive
beams with intensity >= ``min_intensity`` and a valid range; its centre is the
mean beam angle of the run and the mean range of the run, optionally pushed out
by ``beacon_radius`` (the laser sees the near surface of the pole; the centre is
one radius further along the ray).

The default radius is 0: on the Car Park data the measured cluster range minus
the distance from the GPS point (= laser) to the surveyed beacon has a median of
+0.005 m (IQR -0.009 .. +0.024 m, 960 of 964 detections matched within 0.5 m), so
the surveyed positions already correspond to the range the laser reports and a
radius correction would only add a bias.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Ranges at or beyond this are "no return" in the KTH laser data.
KTH_MAX_RANGE = 81.9


class Beacons(NamedTuple):
    """Detected beacon centres: range (m), bearing (rad, the scan's convention), beams per cluster."""

    range: np.ndarray
    bearing: np.ndarray
    n_beams: np.ndarray

    def __len__(self) -> int:  # type: ignore[override]
        return len(self.range)


def extract_beacons(ranges, intensities, angle_min: float, angle_increment: float,
                    min_intensity: float = 1, max_range: float = KTH_MAX_RANGE,
                    min_range: float = 0.0, beacon_radius: float = 0.0,
                    max_range_jump: float | None = 1.0) -> Beacons:
    """Cluster consecutive reflective beams into beacons.

    Beam k has angle ``angle_min + k * angle_increment`` and counts as reflective
    when ``intensities[k] >= min_intensity`` and ``min_range < ranges[k] < max_range``
    (finite).  A run of consecutive reflective beams is split where neighbouring
    ranges differ by more than ``max_range_jump`` (two poles side by side at
    different depths; None disables).  Returns the mean range (+ ``beacon_radius``)
    and mean angle of each cluster, in beam order.
    """
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    inten = np.asarray(intensities, dtype=np.float64).reshape(-1)
    if r.shape != inten.shape:
        raise ValueError(f"ranges ({r.size}) and intensities ({inten.size}) differ in length")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r) & (r > min_range) & (r < max_range) & (inten >= min_intensity)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        empty = np.zeros(0)
        return Beacons(empty, empty.copy(), np.zeros(0, dtype=np.int64))
    brk = np.diff(idx) > 1
    if max_range_jump is not None:
        brk |= np.abs(np.diff(r[idx])) > max_range_jump
    starts = np.concatenate([[0], np.flatnonzero(brk) + 1])
    counts = np.diff(np.append(starts, idx.size))
    rng = np.add.reduceat(r[idx], starts) / counts + beacon_radius
    k = np.add.reduceat(idx.astype(np.float64), starts) / counts
    bearing = angle_min + k * angle_increment
    return Beacons(rng, bearing, counts.astype(np.int64))


def observation_columns(ranges, bearings, ids=None, range_std=0.0, bearing_std=0.0) -> dict:
    """Columns of the project's observation PointCloud2 layout (cloud.OBSERVATION_FIELDS).

    x, y, z in the sensor frame (z = 0), range, bearing, id (-1 = unknown) and
    range_std / bearing_std (0 = "use the configured noise").
    """
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    b = np.asarray(bearings, dtype=np.float64).reshape(-1)
    n = r.size
    ids = np.full(n, -1, dtype=np.int32) if ids is None else np.asarray(ids, dtype=np.int32).reshape(-1)
    return {"x": r * np.cos(b), "y": r * np.sin(b), "z": np.zeros(n), "range": r, "bearing": b,
            "id": ids, "range_std": np.broadcast_to(np.float64(range_std), (n,)).copy(),
            "bearing_std": np.broadcast_to(np.float64(bearing_std), (n,)).copy()}
