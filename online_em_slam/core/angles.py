"""Angle helpers: wrapping and circular statistics."""
from __future__ import annotations

import numpy as np


def wrap_angle(angle):
    """Wrap angles to (-pi, pi].

    Uses atan2(sin, cos) rather than a modulo so that +pi stays +pi and
    values many turns away wrap correctly; works on scalars and arrays.
    """
    wrapped = np.arctan2(np.sin(angle), np.cos(angle))
    # atan2 returns -pi for sin == -0.0; fold it onto the documented +pi.
    return np.where(wrapped <= -np.pi, np.pi, wrapped) if np.ndim(wrapped) else (
        np.pi if wrapped <= -np.pi else float(wrapped))


def circular_mean(angles: np.ndarray, weights: np.ndarray) -> float:
    """Weighted circular mean atan2(sum w sin, sum w cos)."""
    return float(np.arctan2(np.dot(weights, np.sin(angles)), np.dot(weights, np.cos(angles))))
