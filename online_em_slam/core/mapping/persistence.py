"""What an estimator's map file holds and how it comes back (the glue of
:meth:`OnlineEMSlam.save_map` / ``load_map`` around mapfile.py).

A map file holds the landmark table, the M-step's per-landmark state
(``MStep.saved_arrays``), the pose and, when the noise is learned, the noise in
use (``NoiseLearner.saved_values``).  Loading rebuilds the table and the
M-step state, and makes the file's noise the learner's starting point.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import ObservationNoiseConfig
from ..models.angles import wrap_angle
from .landmarks import LandmarkTable


def map_arrays(table: LandmarkTable, m_step) -> dict[str, np.ndarray]:
    """The landmark table and the M-step's per-landmark state, as copies."""
    arrays = {"theta": table.theta, "ids": table.ids, "n_obs": table.n_obs, "confirmed": table.confirmed}
    arrays.update(m_step.saved_arrays(table.theta))
    return {name: np.array(value) for name, value in arrays.items()}


def restore_map(table: LandmarkTable, m_step, arrays: dict[str, np.ndarray]) -> None:
    """Rebuild an empty landmark table and M-step state from :func:`map_arrays` output."""
    m = arrays["theta"].shape[0]
    table.add(np.array(arrays["theta"]), np.array(arrays["ids"]), 0)
    table.n_obs[:] = arrays["n_obs"]
    table.confirmed[:] = arrays["confirmed"]
    table.created[:] = np.zeros(m, dtype=np.int64)
    m_step.restore(arrays, table.theta)


def saved_pose(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """The pose (3,) of a map file (the saving robot's, where a reload relocalises), yaw wrapped."""
    pose = np.array(arrays["pose"], dtype=float)
    pose[2] = wrap_angle(pose[2])
    return pose


def saved_noise(arrays: dict[str, np.ndarray],
                configured: ObservationNoiseConfig) -> tuple[ObservationNoiseConfig, float] | None:
    """(noise, motion scale) of a map file's learned noise on top of ``configured``; None when
    the file has none.  ValueError when its mixture has another number of components than
    ``configured`` (another noise model)."""
    if "noise" not in arrays:
        return None
    weights, scales = arrays["noise_mixture"]
    if len(weights) != len(configured.mixture_weights):
        raise ValueError(f"the map file's noise has {len(weights)} mixture components, "
                         f"the configured noise {len(configured.mixture_weights)}")
    sigma_r, growth, sigma_b, rho, scale = (float(v) for v in arrays["noise"])
    noise = replace(configured, sigma_range=sigma_r, range_growth=growth, sigma_bearing=sigma_b, rho=rho,
                    mixture_weights=tuple(map(float, weights)), mixture_scales=tuple(map(float, scales)))
    if "noise_dof" in arrays:
        noise = replace(noise, dof=float(arrays["noise_dof"]))
    if "noise_serial" in arrays:
        noise = replace(noise, serial_correlation=tuple(float(v) for v in arrays["noise_serial"]))
    if "noise_serial_length" in arrays:
        noise = replace(noise, serial_length=tuple(float(v) for v in arrays["noise_serial_length"]))
    return noise, scale
