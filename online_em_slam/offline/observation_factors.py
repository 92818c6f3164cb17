"""The batch's observation factors (offline/batch.py): the noise law's cost and the lever arm.

:func:`observation_noise_model` makes an observation cost what the estimator's noise law says
(docs/METHOD.md, "The batch reference"); :func:`lever_arm_factor` is a range-bearing factor
for a sensor off the base's origin, which GTSAM's BearingRangeFactor2D does not offer.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.models.observation import MIN_DISTANCE


def observation_noise_model(gtsam, cov: np.ndarray, noise):
    """The GTSAM noise model of an observation with covariance ``cov`` under the noise law ``noise``
    (``config.noise``): a Gaussian N(0, cov); a Student-t with nu = ``noise.dof`` as its negative
    log-likelihood (nu + 2) / 2 log(1 + d2 / nu), d2 the Mahalanobis distance under ``cov``, which
    is a Cauchy kernel rho(x) = k^2 / 2 log(1 + x^2 / k^2) with k^2 = nu + 2 on the error whitened
    by cov nu / (nu + 2) (Levenberg-Marquardt then reweighs each observation by the t's weight
    (nu + 2) / (nu + d2), as the estimator's E-step does); a mixture as its core component."""
    if noise.model != "student_t":
        return gtsam.noiseModel.Gaussian.Covariance(cov)
    nu = float(noise.dof)
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(math.sqrt(nu + 2.0)),
                                          gtsam.noiseModel.Gaussian.Covariance(cov * (nu / (nu + 2.0))))


def lever_arm_measurement(pose, landmark, offset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """h = (range, bearing) of ``landmark`` from a sensor at ``offset`` (x, y, yaw) on the base
    ``pose``, and its Jacobians in the Pose2 tangent space (X Exp(xi): xi_t in the body frame)
    (2, 3) and in the landmark (2, 2)."""
    x, y, phi = (float(v) for v in pose)
    ox, oy, oyaw = offset
    c, s = math.cos(phi), math.sin(phi)
    dx = float(landmark[0]) - (x + c * ox - s * oy)
    dy = float(landmark[1]) - (y + s * ox + c * oy)
    q = max(dx * dx + dy * dy, MIN_DISTANCE ** 2)
    r = math.sqrt(q)
    h = np.array([r, wrap_angle(math.atan2(dy, dx) - phi - oyaw)])
    H_l = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
    # Sensor point p + R(phi) (xi_t + xi_phi (-oy, ox)): dh/dxi = -H_l R [I | (-oy, ox)], bearing -1 on xi_phi.
    lever = np.array([[c, -s, -c * oy - s * ox], [s, c, -s * oy + c * ox]])
    H_x = -H_l @ lever
    H_x[1, 2] -= 1.0
    return h, H_x, H_l


def lever_arm_factor(gtsam, noise_model, pose_key, landmark_key, y: np.ndarray, offset):
    """Range-bearing factor with the sensor lever arm, error h - y in (range, bearing) order."""
    y = np.array(y, dtype=float)

    def error(this, values, jacobians):
        pose = values.atPose2(this.keys()[0])
        h, H_x, H_l = lever_arm_measurement((pose.x(), pose.y(), pose.theta()),
                                            np.asarray(values.atPoint2(this.keys()[1]), float), offset)
        if jacobians is not None:
            jacobians[0], jacobians[1] = H_x, H_l
        return np.array([h[0] - y[0], wrap_angle(h[1] - y[1])])

    return gtsam.CustomFactor(noise_model, [pose_key, landmark_key], error)
