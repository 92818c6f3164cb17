"""Fitting an estimated landmark map onto the surveyed one: the rigid fit that splits the
landmark RMSE into *shape* and *frame*, and the similarity fit that reads the map's *scale*.

Landmark RMSE mixes two different failures: a map that is the right shape but
rotated / shifted as a whole (the gauge a SLAM run fixes only through its
initial pose and its drift: the *frame* error) and a deformed map (the
*shape* error).  Definitions, for n landmarks e_i estimated, t_i true, paired:

    rmse^2  = 1/n sum |e_i - t_i|^2
    shape^2 = min over rotations R, translations c of 1/n sum |R e_i + c - t_i|^2
    frame^2 = rmse^2 - shape^2     (>= 0: R = I, c = 0 is a candidate)

so rmse^2 = shape^2 + frame^2: frame is the part of the error that one rigid
motion of the whole map removes.  The shape keeps the map's scale, which the ranges set.

A map of the right shape at the wrong size is deformed for the rigid fit: its shape error
grows with the distance from the map's centre.  A single robot whose commanded speed gain is
learned cannot see a scale error of its range sensor (the map, the trajectory, the ranges'
scale and the speed gain scale together); :func:`map_scale_split` reads it: the map's size
against the truth's and the shape error left once a similarity (rotation, translation and
scale) is fitted.
"""
from __future__ import annotations

import numpy as np


def rotate_points(points, angle) -> np.ndarray:
    """Points (..., n, 2) rotated by ``angle`` (...,) about the origin."""
    p = np.asarray(points, dtype=float)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], axis=-1)


def rigid_fit_2d(estimated, truth) -> tuple[np.ndarray, np.ndarray]:
    """Best rigid motion of ``estimated`` onto ``truth`` (2-D Kabsch, closed form).

    estimated, truth: (..., n, 2), rows paired; leading axes are a batch.
    Returns the rotation angle (...,) and translation c (..., 2) minimising
    sum_i |R(angle) e_i + c - t_i|^2: with centred points a_i, b_i the angle is
    atan2(sum a_i x b_i, sum a_i . b_i) and c = mean(t) - R mean(e).
    """
    e, t = np.asarray(estimated, dtype=float), np.asarray(truth, dtype=float)
    mu_e, mu_t = e.mean(axis=-2, keepdims=True), t.mean(axis=-2, keepdims=True)
    a, b = e - mu_e, t - mu_t
    angle = np.arctan2(np.sum(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], axis=-1),
                       np.sum(a * b, axis=(-2, -1)))
    return angle, (mu_t - rotate_points(mu_e, angle))[..., 0, :]


def fitted_onto(points, estimated, truth) -> np.ndarray:
    """``points`` (n, 2) moved by the best rigid fit of ``estimated`` onto ``truth`` (m, 2), paired."""
    angle, c = rigid_fit_2d(estimated, truth)
    return rotate_points(np.asarray(points, dtype=float), angle) + c


def map_error_split(estimated, truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmark RMSE, shape error and frame error (...,) of estimated vs true
    landmarks (..., n, 2), rows paired (definitions above); NaN when n = 0."""
    e, t = np.asarray(estimated, dtype=float), np.asarray(truth, dtype=float)
    if e.shape[-2] == 0:
        nan = np.full(e.shape[:-2], np.nan)
        return nan, nan.copy(), nan.copy()
    mse = np.mean(np.sum((e - t) ** 2, axis=-1), axis=-1)
    angle, c = rigid_fit_2d(e, t)
    # Residuals of the fitted map rather than the closed-form minimum
    # |a|^2 + |b|^2 - 2 |(sum a.b, sum a x b)|, which cancels badly for large maps.
    fitted = rotate_points(e, angle) + c[..., None, :]
    shape_sq = np.minimum(np.mean(np.sum((fitted - t) ** 2, axis=-1), axis=-1), mse)  # <= mse up to round-off
    return np.sqrt(mse), np.sqrt(shape_sq), np.sqrt(mse - shape_sq)


def map_scale_split(estimated, truth) -> tuple[float, float]:
    """(map scale, shape error after the best similarity fit) of estimated vs true landmarks
    (n, 2), rows paired; (nan, nan) for fewer than 2 landmarks.

    The similarity s R e_i + c best onto t_i: with centred points a_i, b_i, R the rigid fit's
    rotation and s = sum (R a_i) . b_i / sum |a_i|^2.  The map scale is 1 / s: above 1 the map
    is larger than the truth, below 1 smaller.
    """
    e, t = np.asarray(estimated, dtype=float).reshape(-1, 2), np.asarray(truth, dtype=float).reshape(-1, 2)
    if len(e) < 2:
        return float("nan"), float("nan")
    a, b = e - e.mean(axis=0), t - t.mean(axis=0)
    angle, _ = rigid_fit_2d(e, t)
    turned = rotate_points(a, angle)
    s = float(np.sum(turned * b) / np.sum(a * a))
    if not s > 0.0:
        return float("nan"), float("nan")
    return 1.0 / s, float(np.sqrt(np.mean(np.sum((s * turned - b) ** 2, axis=1))))

