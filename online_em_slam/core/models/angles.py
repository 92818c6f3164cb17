"""Angle helpers: wrapping and circular statistics."""
from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi


def wrap_angle(angle):
    """Wrap angles to (-pi, pi]: pi - ((pi - a) mod 2 pi).

    One floating-point modulo instead of atan2(sin, cos): this runs on every
    bearing and heading of every particle.  +pi stays +pi, -pi maps to +pi,
    and values many turns away wrap correctly; scalars give floats.
    """
    wrapped = math.pi - np.mod(math.pi - np.asarray(angle, dtype=float), _TWO_PI)
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def circular_mean(angles: np.ndarray, weights: np.ndarray) -> float:
    """Weighted circular mean atan2(sum w sin, sum w cos)."""
    return float(np.arctan2(np.dot(weights, np.sin(angles)), np.dot(weights, np.cos(angles))))
