"""Range-bearing observation model, its Jacobians and noise laws.

All functions broadcast over leading axes, so one call serves every particle and
every landmark.  Notation of docs/METHOD.md: pose X = (x, y, phi),
landmark theta_k in R^2, observation y = h(X, theta_k) + W with
h = (|theta_k - p|, atan2(dy, dx) - phi), p the sensor position.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .angles import wrap_angle
from ..config import ObservationNoiseConfig, SensorConfig

_LOG_2PI = math.log(2.0 * math.pi)
# Below this distance (m) the bearing is undefined; clamp to keep H finite.
MIN_DISTANCE = 1e-3


def sensor_poses(poses: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """Pose of the sensor in the world for base poses (..., 3)."""
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    out = np.empty_like(poses, dtype=float)
    out[..., 0] = poses[..., 0] + c * sensor.offset_x - s * sensor.offset_y
    out[..., 1] = poses[..., 1] + s * sensor.offset_x + c * sensor.offset_y
    out[..., 2] = poses[..., 2] + sensor.offset_yaw
    return out


def predict_observation(sensor_pose: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """h(X, theta): (range, bearing) of landmarks (..., 2) seen from sensor poses (..., 3).

    Bearing is wrapped to (-pi, pi].  Shapes broadcast: (N,1,3) with (1,K,2) gives (N,K,2).
    """
    dx = landmarks[..., 0] - sensor_pose[..., 0]
    dy = landmarks[..., 1] - sensor_pose[..., 1]
    out = np.empty(np.broadcast(dx, dy).shape + (2,))
    out[..., 0] = np.hypot(dx, dy)
    out[..., 1] = wrap_angle(np.arctan2(dy, dx) - sensor_pose[..., 2])
    return out


def landmark_jacobian(sensor_pose: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """H = dh/dtheta = [[dx/r, dy/r], [-dy/q, dx/q]] with q = r^2 (docs/METHOD.md, "Model").

    The distance is clamped at ``MIN_DISTANCE`` so a landmark on top of the
    sensor gives a large but finite Jacobian instead of NaN.
    """
    dx = landmarks[..., 0] - sensor_pose[..., 0]
    dy = landmarks[..., 1] - sensor_pose[..., 1]
    q = np.maximum(dx * dx + dy * dy, MIN_DISTANCE ** 2)
    r = np.sqrt(q)
    H = np.empty(np.broadcast(dx, dy).shape + (2, 2))
    H[..., 0, 0] = dx / r
    H[..., 0, 1] = dy / r
    H[..., 1, 0] = -dy / q
    H[..., 1, 1] = dx / q
    return H


def pose_jacobian(poses: np.ndarray, landmarks: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """dh/dX (..., 2, 3) for base poses, including the lever arm of the sensor offset."""
    sp = sensor_poses(poses, sensor)
    H_l = landmark_jacobian(sp, landmarks)
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    # d(sensor position)/d(phi) for the lever arm (offset_x, offset_y).
    dpx = -s * sensor.offset_x - c * sensor.offset_y
    dpy = c * sensor.offset_x - s * sensor.offset_y
    shape = np.broadcast_shapes(H_l.shape[:-2], dpx.shape)
    J = np.empty(shape + (2, 3))
    J[..., :, 0] = -H_l[..., :, 0]
    J[..., :, 1] = -H_l[..., :, 1]
    J[..., :, 2] = -(H_l[..., :, 0] * dpx[..., None] + H_l[..., :, 1] * dpy[..., None])
    J[..., 1, 2] -= 1.0
    return J


def inverse_observation(sensor_pose: np.ndarray, observation: np.ndarray) -> np.ndarray:
    """Landmark position that would produce ``observation`` (range, bearing) from the sensor pose."""
    angle = sensor_pose[..., 2] + observation[..., 1]
    out = np.empty(np.broadcast_shapes(sensor_pose.shape[:-1], observation.shape[:-1]) + (2,))
    out[..., 0] = sensor_pose[..., 0] + observation[..., 0] * np.cos(angle)
    out[..., 1] = sensor_pose[..., 1] + observation[..., 0] * np.sin(angle)
    return out


def innovation(observation: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """y - h with the bearing difference wrapped to (-pi, pi]."""
    nu = observation - predicted
    nu[..., 1] = wrap_angle(nu[..., 1])
    return nu


def noise_covariance(noise: ObservationNoiseConfig, ranges: np.ndarray,
                     range_std: np.ndarray | None = None,
                     bearing_std: np.ndarray | None = None) -> np.ndarray:
    """R (..., 2, 2) per observation.

    Default R = [[sigma_r^2, rho], [rho, sigma_b^2]] with sigma_r growing by
    ``range_growth`` per metre of range; per-observation standard deviations,
    when given (not 0 or NaN; validated by types.Observations.valid_std), replace the
    configured ones and drop rho.
    """
    ranges = np.asarray(ranges, dtype=float)
    sr = noise.sigma_range + noise.range_growth * np.maximum(ranges, 0.0)
    # The configured bearing std and rho stay scalars or broadcast (R is made for every scan,
    # several times); given stds replace them where valid.
    sb, rho = noise.sigma_bearing, noise.rho * (sr / noise.sigma_range)
    if range_std is not None:
        good = np.isfinite(range_std) & (np.asarray(range_std) > 0)
        sr = np.where(good, range_std, sr)
        rho = np.where(good, 0.0, rho)
    if bearing_std is not None:
        good = np.isfinite(bearing_std) & (np.asarray(bearing_std) > 0)
        sb = np.where(good, bearing_std, sb)
        rho = np.where(good, 0.0, rho)
    R = np.empty(np.shape(sr) + (2, 2))
    R[..., 0, 0] = sr * sr
    R[..., 1, 1] = sb * sb
    R[..., 0, 1] = R[..., 1, 0] = rho
    return R


def information_noise(noise: ObservationNoiseConfig) -> ObservationNoiseConfig:
    """The noise under which independent observations inform as much as serially correlated ones do.

    A landmark's errors correlated by c from one scan to the next (AR(1)) make the mean of n
    observations vary as R (1 + c) / (1 - c) / n, not R / n: each observation weighs as
    (1 - c) / (1 + c) of an independent one.  R's standard deviations scale by the square
    roots of those factors (range: sigma_range and range_growth; rho by both); ``noise`` itself
    when uncorrelated.  For the likelihood and the M-step's precision; the gates and distances
    keep one observation's spread, R.
    """
    c_r, c_b = noise.serial_correlation
    if c_r == 0.0 and c_b == 0.0:
        return noise
    f_r, f_b = math.sqrt((1.0 + c_r) / (1.0 - c_r)), math.sqrt((1.0 + c_b) / (1.0 - c_b))
    return replace(noise, sigma_range=noise.sigma_range * f_r, range_growth=noise.range_growth * f_r,
                   sigma_bearing=noise.sigma_bearing * f_b, rho=noise.rho * f_r * f_b, serial_correlation=(0.0, 0.0))


def serial_decays(noise: ObservationNoiseConfig) -> bool:
    """The serial correlation decays with the viewpoint's change (noise.serial_length), so each
    observation has its own c (:func:`observation_correlation`)."""
    return any(noise.serial_length) and any(noise.serial_correlation)


def viewpoint_change(previous: np.ndarray, pose: np.ndarray, turn_length: float) -> np.ndarray:
    """v (P,) of the sensor pose ``pose`` (3,) or (P, 3) since ``previous`` (P, 3): the distance
    travelled plus ``turn_length`` per radian of heading change; a row of NaN (no previous
    sighting) gives inf."""
    d = pose - previous
    v = np.hypot(d[..., 0], d[..., 1]) + turn_length * np.abs(wrap_angle(d[..., 2]))
    return np.where(np.isnan(v), np.inf, v)


def observation_correlation(noise: ObservationNoiseConfig, v: np.ndarray) -> np.ndarray:
    """Each observation's serial correlation c = c0 exp(-v / l) (P, 2) after a viewpoint change
    ``v`` (P,) since its landmark's previous sighting (inf: none, c = 0); a length l of 0 keeps c0."""
    c0, length = np.asarray(noise.serial_correlation, dtype=float), np.asarray(noise.serial_length, dtype=float)
    decaying = length > 0.0
    with np.errstate(invalid="ignore"):
        decay = np.exp(-v[:, None] / np.where(decaying, length, 1.0))
    return c0 * np.where(decaying, decay, 1.0)


def serially_weighed(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """R (P, 2, 2) with each observation's standard deviations scaled as :func:`information_noise`
    does, by sqrt((1 + c_j) / (1 - c_j)), with its own correlation c (P, 2)."""
    f = np.sqrt((1.0 + c) / (1.0 - c))
    return R * f[:, :, None] * f[:, None, :]


def chi_square_2_quantile(probability: float) -> float:
    """The d2 below which a chi-square(2) variable falls with ``probability``: its CDF is
    1 - exp(-d2 / 2), so -2 log(1 - p) (scipy.stats' chi2.ppf to an ulp, without the import
    of scipy.stats, about a third of the node's start)."""
    return float(-2.0 * math.log1p(-probability))


def inv_det_2x2(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form inverse and determinant of 2x2 matrices (..., 2, 2)."""
    det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
    safe = np.where(np.abs(det) > 1e-300, det, 1e-300)
    inv = np.empty_like(S)
    inv[..., 0, 0] = S[..., 1, 1] / safe
    inv[..., 1, 1] = S[..., 0, 0] / safe
    inv[..., 0, 1] = -S[..., 0, 1] / safe
    inv[..., 1, 0] = -S[..., 1, 0] / safe
    return inv, det


def mahalanobis_2d(nu: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """nu^T S^-1 nu and log det S for 2-vectors."""
    inv, det = inv_det_2x2(S)
    return _quadratic_form(nu, inv), np.log(np.maximum(det, 1e-300))


def mahalanobis_d2(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """nu^T S^-1 nu (...) for 2-vectors nu (..., 2), S (..., 2, 2): mahalanobis_2d without log det S."""
    return _quadratic_form(nu, inv_det_2x2(S)[0])


def _quadratic_form(nu: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """nu^T inv nu (...) for 2-vectors nu (..., 2) and 2x2 matrices inv (..., 2, 2)."""
    return (nu[..., 0] * (inv[..., 0, 0] * nu[..., 0] + inv[..., 0, 1] * nu[..., 1])
            + nu[..., 1] * (inv[..., 1, 0] * nu[..., 0] + inv[..., 1, 1] * nu[..., 1]))


def gaussian_loglik(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """log N(nu; 0, S) for 2-vectors."""
    d2, logdet = mahalanobis_2d(nu, S)
    return -0.5 * (d2 + logdet) - _LOG_2PI


def noise_loglik(noise: ObservationNoiseConfig, nu: np.ndarray, S: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Log-likelihood of innovations and the E-step of the noise's latent variable.

    Gaussian:  log N(nu; 0, S); latent all 1 (one component).
    Mixture:   log sum_c weight_c N(nu; 0, scale_c S); latent (..., C) the
               responsibilities, the posterior component probabilities.
    Student-t: log t_dof(nu; 0, S); latent (..., 1) the posterior mean of the
               precision scale tau ~ Gamma(dof/2, dof/2), u = (dof + 2) / (dof + d2).
    Returns (loglik (...), latent (..., C)).
    """
    if noise.model == "gaussian":
        return gaussian_loglik(nu, S), np.ones(nu.shape[:-1] + (1,))
    d2, logdet = mahalanobis_2d(nu, S)
    if noise.model == "student_t":
        return student_t_loglik(d2, logdet, noise.dof), student_t_weight(d2, noise.dof)[..., None]
    scales = np.asarray(noise.mixture_scales, dtype=float)
    log_weights = np.log(np.maximum(np.asarray(noise.mixture_weights, dtype=float), 1e-300))
    comp = (log_weights - _LOG_2PI - 0.5 * (d2[..., None] / scales + logdet[..., None]
                                             + 2.0 * np.log(scales)))
    top = comp.max(axis=-1, keepdims=True)
    total = top[..., 0] + np.log(np.exp(comp - top).sum(axis=-1))
    return total, np.exp(comp - total[..., None])


def student_t_loglik(d2: np.ndarray, logdet: np.ndarray, dof: float) -> np.ndarray:
    """log t_dof(nu; 0, S) in 2-D from d2 = nu^T S^-1 nu and log det S:
    log Gamma((dof+2)/2) - log Gamma(dof/2) - log(dof pi) - logdet/2 - (dof+2)/2 log(1 + d2/dof)."""
    const = math.lgamma(0.5 * dof + 1.0) - math.lgamma(0.5 * dof) - math.log(dof * math.pi)
    return const - 0.5 * logdet - 0.5 * (dof + 2.0) * np.log1p(d2 / dof)


def student_t_weight(d2: np.ndarray, dof: float) -> np.ndarray:
    """E[tau | nu] = (dof + 2) / (dof + d2): the precision factor an innovation gets in EM."""
    return (dof + 2.0) / (dof + d2)


def component_precision_weight(noise: ObservationNoiseConfig, responsibilities: np.ndarray) -> np.ndarray:
    """sum_c r_c / scale_c: the factor multiplying R^-1 in the expected quadratic form.

    With the mixture, the complete-data log-likelihood is quadratic given the
    component; its expectation weights R_c^-1 = R^-1 / scale_c by r_c.  With the
    Student-t it is quadratic given tau, and the factor is E[tau | nu] (the latent).
    """
    if noise.model != "mixture":
        return responsibilities[..., 0]
    return responsibilities @ (1.0 / np.asarray(noise.mixture_scales, dtype=float))
