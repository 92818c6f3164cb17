"""Vehicle motion models, vectorised over particles.

Each model maps poses (N, 3) and one control to the noise-free next pose
f(X, u), its Jacobian F = df/dX and the state-space noise covariance
G Q G^T (G = df/dnoise).  The particle filter uses the Gaussian approximation
of the transition

    m(x, x') = N(x'; f(x, u), G Q G^T)                                    (T)

compounded over the control steps between two observation times (EKF-style
moments, F Sigma F^T + G Q G^T).  The same density (T) serves as the proposal
and inside the backward kernel of the smoother, so sampling and smoothing are
consistent: this is the seed's "Gaussian approximation of the prior m(x, x')".

Controls may be one row (2,) or one row per pose (N, 2), with dt a scalar or
(N,): :func:`integrate_segments` uses that to apply all the control messages
received between two scans in one vectorised pass.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from .angles import wrap_angle
from ..config import MOTION_MODELS, MotionConfig


def _noise_cov(G, variances) -> np.ndarray:
    """G diag(variances) G^T (..., 3, 3) from G's entries ``G[a][j]`` (a: x, y, yaw; j: the two
    controls) and the two controls' ``variances``, each broadcastable to the batch.

    Entry by entry over the batch: for hundreds of 3 x 2 matrices far fewer and cheaper
    numpy calls than a batched matmul.
    """
    GV = [(row[0] * variances[0], row[1] * variances[1]) for row in G]
    entries = {(a, b): GV[a][0] * G[b][0] + GV[a][1] * G[b][1] for a in range(3) for b in range(a, 3)}
    Q = np.empty(np.broadcast_shapes(*(e.shape for e in entries.values())) + (3, 3))
    for (a, b), value in entries.items():
        Q[..., a, b] = Q[..., b, a] = value
    Q += 0.0        # a zero entry is +0.0, as numpy's sum over the two controls makes it
    return Q


def _control_variances(config: MotionConfig, control: np.ndarray, dt: float) -> tuple:
    """Per-step control variances (speed's, steering's or yaw rate's), scaled as continuous-time
    white noise.

    sigma is specified for ``noise_reference_period`` seconds; per step of dt
    the variance is sigma^2 * ref / dt so that the integrated pose variance
    per second does not depend on the control rate.  Each control's sigma^2 is
    a constant part plus a part proportional to the control's square,
    sigma_u^2 = sigma^2 + (sigma_relative u)^2: a command's error grows with it.
    """
    scale = config.noise_reference_period / np.maximum(dt, 1e-6)
    speed, steering = config.sigma_speed ** 2, config.sigma_steering ** 2
    if config.sigma_speed_relative:              # off by default: the constant noise alone
        speed = speed + (config.sigma_speed_relative * control[..., 0]) ** 2
    if config.sigma_steering_relative:
        steering = steering + (config.sigma_steering_relative * control[..., 1]) ** 2
    return speed * scale, steering * scale


def _heading_noise(config: MotionConfig, dt: float) -> float:
    return config.sigma_heading ** 2 * dt / config.noise_reference_period


# Every model is two functions (integrate_segments evaluates them once per flush): the
# control's factors, ``_<model>_segment(config, control, dt)``, its yaw increment first (no
# model's depends on the pose); and ``_<model>_moves(config, factors, yaw)``, from the
# headings yaw (...) the move (dx, dy, dyaw), the lever (s_x, s_y) = d position / d yaw and
# G Q G^T (..., 3, 3).  The model itself, (config, poses, control, dt) -> (f(X, u), F, G Q G^T),
# composes them (``_on_poses``).


def _on_poses(poses: np.ndarray, move, lever, Q: np.ndarray):
    """(f(X, u), F, G Q G^T) for poses (N, 3) from a model's move, lever and noise."""
    mean = poses.copy()
    mean[:, 0] += move[0]
    mean[:, 1] += move[1]
    mean[:, 2] += move[2]
    F = np.broadcast_to(np.eye(3), (poses.shape[0], 3, 3)).copy()
    F[:, 0, 2], F[:, 1, 2] = lever
    return mean, F, Q


def _bicycle_segment(config: MotionConfig, control: np.ndarray, dt):
    v, psi = control[..., 0], control[..., 1]
    B, step, sin_psi = config.wheelbase, v * dt, np.sin(psi)
    return (step * sin_psi / B, psi, step, dt * sin_psi / B, step * np.cos(psi) / B,
            _control_variances(config, control, dt), _heading_noise(config, dt), dt)


def _bicycle_moves(config: MotionConfig, factors, yaw: np.ndarray):
    dyaw, psi, step, g_yaw_v, g_yaw_psi, variances, heading_var, dt = factors
    heading = yaw + psi
    c, s = np.cos(heading), np.sin(heading)
    dx, dy = step * c, step * s
    Q = _noise_cov(((dt * c, -dy), (dt * s, dx), (g_yaw_v, g_yaw_psi)), variances)
    Q[..., 2, 2] += heading_var
    return (dx, dy, dyaw), (-dy, dx), Q


def bicycle(config: MotionConfig, poses: np.ndarray, control: np.ndarray, dt: float):
    """Seed bicycle model, control u = (v, psi), wheelbase B (docs/METHOD.md, "Model"):

    X' = X + (v dt cos(phi + psi), v dt sin(phi + psi), v dt sin(psi) / B).
    """
    return _on_poses(poses, *_bicycle_moves(config, _bicycle_segment(config, control, dt), poses[:, 2]))


def _acfr_segment(config: MotionConfig, control: np.ndarray, dt):
    v_e, alpha = control[..., 0], control[..., 1]
    L, H = config.wheelbase, config.encoder_offset
    tan_a = np.tan(alpha)
    sec2 = 1.0 + tan_a ** 2
    denom = 1.0 - tan_a * H / L
    k = 1.0 / denom
    v_c = v_e * k
    dvc_dalpha = v_e * (H / L) * sec2 / denom ** 2
    step = v_c * dt
    return (step * tan_a / L, step, k * dt, dvc_dalpha * dt, k * dt * tan_a / L,
            dt * (dvc_dalpha * tan_a + v_c * sec2) / L, _control_variances(config, control, dt),
            _heading_noise(config, dt))


def _acfr_moves(config: MotionConfig, factors, yaw: np.ndarray):
    dyaw, step, k_dt, dvc_dt, g_yaw_v, g_yaw_alpha, variances, heading_var = factors
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = step * c, step * s
    Q = _noise_cov(((k_dt * c, dvc_dt * c), (k_dt * s, dvc_dt * s), (g_yaw_v, g_yaw_alpha)), variances)
    Q[..., 2, 2] += heading_var
    return (dx, dy, dyaw), (-dy, dx), Q


def acfr(config: MotionConfig, poses: np.ndarray, control: np.ndarray, dt: float):
    """ACFR ute (KTH datasets), pose of the rear-axle centre, control u = (v_e, alpha).

    v_c = v_e / (1 - tan(alpha) H / L) converts the rear-left encoder speed to the
    centre speed; X' = X + (v_c dt cos phi, v_c dt sin phi, v_c dt tan(alpha) / L).
    The laser point of the dataset README's model is this pose plus the sensor
    offset (a, b), so the observation model carries the lever arm.
    """
    return _on_poses(poses, *_acfr_moves(config, _acfr_segment(config, control, dt), poses[:, 2]))


def _unicycle_segment(config: MotionConfig, control: np.ndarray, dt):
    v, omega = control[..., 0], control[..., 1]
    return (omega * dt, 0.5 * omega * dt, v * dt, 0.5 * v * dt * dt, _control_variances(config, control, dt),
            _heading_noise(config, dt), dt)


def _unicycle_moves(config: MotionConfig, factors, yaw: np.ndarray):
    dyaw, half_turn, step, half_step_dt, variances, heading_var, dt = factors
    heading = yaw + half_turn
    c, s = np.cos(heading), np.sin(heading)
    dx, dy = step * c, step * s
    Q = _noise_cov(((dt * c, -(half_step_dt * s)), (dt * s, half_step_dt * c), (0.0, dt)), variances)
    Q[..., 2, 2] += heading_var
    return (dx, dy, dyaw), (-dy, dx), Q


def unicycle(config: MotionConfig, poses: np.ndarray, control: np.ndarray, dt: float):
    """Control u = (v, omega): X' = X + (v dt cos(phi + omega dt / 2), v dt sin(.), omega dt)."""
    return _on_poses(poses, *_unicycle_moves(config, _unicycle_segment(config, control, dt), poses[:, 2]))


def odometry_increment(previous: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Odometry control (dx, dy, dphi): ``current`` odometry pose in the frame of ``previous``,
    (dx, dy) = R(-phi_prev) (p_cur - p_prev), dphi = wrap(phi_cur - phi_prev)."""
    c, s = np.cos(previous[2]), np.sin(previous[2])
    dx, dy = current[0] - previous[0], current[1] - previous[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_angle(current[2] - previous[2])])


def _odometry_segment(config: MotionConfig, increment: np.ndarray, dt):
    dx, dy, dphi = increment[..., 0], increment[..., 1], increment[..., 2]
    dist = np.hypot(dx, dy)
    # A robot standing still gets no odometry noise (only the per-step jitter).
    moved = (dist > 0) | (dphi != 0)
    sig_t = np.where(moved, config.odometry_translation_std, 0.0) + config.odometry_translation_per_meter * dist
    sig_r = (np.where(moved, config.odometry_rotation_std, 0.0)
             + config.odometry_rotation_per_radian * abs(dphi)
             + config.odometry_rotation_per_meter * dist)
    return dphi, dx, dy, sig_t ** 2, sig_r ** 2 + _heading_noise(config, dt)


def _odometry_moves(config: MotionConfig, factors, yaw: np.ndarray):
    dphi, dx, dy, var_t, var_r = factors
    c, s = np.cos(yaw), np.sin(yaw)
    Q = np.zeros(np.broadcast_shapes(c.shape, np.shape(var_t)) + (3, 3))
    # Isotropic translation noise is invariant under the body-to-world rotation.
    Q[..., 0, 0] = Q[..., 1, 1] = var_t
    Q[..., 2, 2] = var_r
    return (c * dx - s * dy, s * dx + c * dy, dphi), (-s * dx - c * dy, c * dx - s * dy), Q


def odometry(config: MotionConfig, poses: np.ndarray, increment: np.ndarray, dt: float):
    """Odometry increment u = (dx, dy, dphi) in the previous body frame:

    X' = X + (R(phi) (dx, dy), dphi), noise in the body frame with standard
    deviations growing with the distance and angle travelled.
    """
    return _on_poses(poses, *_odometry_moves(config, _odometry_segment(config, increment, dt), poses[:, 2]))


# The equations of every model of the registry (config.MOTION_INPUTS): the function of its name,
# and its two parts (control factors, moves from headings) for integrate_segments.
MODELS = {name: globals()[name] for name in MOTION_MODELS}
SEGMENT_PARTS = {name: (globals()[f"_{name}_segment"], globals()[f"_{name}_moves"]) for name in MOTION_MODELS}


# The motion model's gains (calibrated), in the order the noise learner estimates them; the
# third only when it learns motion_gain_in_place.
GAIN_NAMES = ("translation_gain", "rotation_gain", "rotation_in_place_gain")
# The drive's dead time (motion.control_delay), learned with the gains (noise_learning motion_delay):
# a shift of the command stream moves the poses linearly to first order, as a gain does.
DELAY = "control_delay"
# The unicycle's turn per metre driven (motion.turn_per_meter), learned the same way (motion_drift).
DRIFT = "turn_per_meter"
# A commanded speed below this (m/s) is a turn in place (rotation_in_place_gain).
IN_PLACE_SPEED = 1e-3


def gain(config: MotionConfig, name: str) -> float:
    """The gain ``name`` in use: rotation_in_place_gain 0 is the rotation gain."""
    value = getattr(config, name)
    return config.rotation_gain if name == "rotation_in_place_gain" and value == 0.0 else value


def calibrated(config: MotionConfig, control: np.ndarray) -> np.ndarray:
    """The motion input times its gains: (speed, steering or yaw rate) by (translation_gain,
    rotation_gain), the turning by rotation_in_place_gain where the speed is below
    IN_PLACE_SPEED; an odometry increment (dx, dy, dphi) by (translation, translation, rotation).
    The unicycle's yaw rate then gains turn_per_meter times the speed delivered (validated: 0 for
    the other models)."""
    control = np.asarray(control, dtype=float)
    t, r, r0 = config.translation_gain, config.rotation_gain, gain(config, "rotation_in_place_gain")
    k = config.turn_per_meter
    if t == 1.0 and r == 1.0 and r0 == 1.0 and k == 0.0:
        return control
    if control.shape[-1] == 3:
        return control * np.array([t, t, r])
    if r0 == r and k == 0.0:
        return control * np.array([t, r])
    speed = control[..., 0] * t
    turn = control[..., 1] * (r if r0 == r else np.where(np.abs(control[..., 0]) < IN_PLACE_SPEED, r0, r))
    return np.stack([speed, turn + k * speed if k != 0.0 else turn], axis=-1)


def propagate(config: MotionConfig, poses: np.ndarray, control: np.ndarray, dt: float):
    """Dispatch to the configured model: returns (f(X, u), F, G Q G^T) for the calibrated input."""
    return MODELS[config.model](config, np.asarray(poses, dtype=float), calibrated(config, control), dt)


def _through_lever(P: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A P A^T for A = I + s e_yaw^T, s (..., 2) the position-by-yaw sensitivity.

    Every model's Jacobian has this form (position moves with the yaw only) and
    such matrices multiply by adding their s: F_K ... F_1 = I + (sum s_k) e_yaw^T.
    """
    s3 = np.zeros(s.shape[:-1] + (3,))
    s3[..., :2] = s
    c = P[..., :, 2]
    return (P + s3[..., :, None] * c[..., None, :] + c[..., :, None] * s3[..., None, :]
            + P[..., 2, 2][..., None, None] * s3[..., :, None] * s3[..., None, :])


@dataclass(frozen=True)
class SegmentFrame:
    """K control segments compounded in the frame of the starting heading (the same for
    every pose, :func:`compound_segments`): the move ``dx``, ``dy``, the yaw turned, the
    lever total sum_k s_k (2,) and the noise sum_k A_k Q_k A_k^T (3, 3)."""

    dx: float
    dy: float
    yaw: float
    lever: np.ndarray
    noise: np.ndarray


def compound_segments(config: MotionConfig, controls: np.ndarray, dts: np.ndarray) -> SegmentFrame | None:
    """The K segments' :class:`SegmentFrame` (None for none): each model's control factors and
    its moves, levers and G Q G^T evaluated once per segment at the headings turned so far,
    the Jacobians I + s_k e_yaw^T compounded as P_K = A_0 P_0 A_0^T + sum_k A_k Q_k A_k^T,
    A_k = I + (sum_{j>k} s_j) e_yaw^T."""
    controls = calibrated(config, controls)
    dts = np.asarray(dts, dtype=float)
    k = dts.shape[0]
    if k == 0:
        return None
    segment, moves = SEGMENT_PARTS[config.model]
    factors = segment(config, controls[:, None, :], dts[:, None])             # (K, 1) each
    yaw_steps = np.zeros(k) + factors[0][:, 0]
    yaw_before = np.concatenate([[0.0], np.cumsum(yaw_steps)[:-1]])
    (dx, dy, _), lever, Q = moves(config, factors, yaw_before[:, None])       # (K, 1): start's heading frame
    s = np.stack([lever[0][:, 0], lever[1][:, 0]], axis=-1)                   # (K, 2)
    from_k = np.cumsum(s[::-1], axis=0)[::-1]                                 # sum_{j >= k} s_j
    return SegmentFrame(float(dx.sum()), float(dy.sum()), float(yaw_steps.sum()), from_k[0],
                        _through_lever(Q[:, 0], from_k - s).sum(axis=0))


def integrate_segments(config: MotionConfig, poses: np.ndarray, covariances: np.ndarray,
                       controls: np.ndarray, dts: np.ndarray, with_jacobian: bool = False):
    """Apply K consecutive control segments to every pose in one vectorised pass.

    Equivalent to K calls of :func:`propagate` (the calibrated inputs) with mean <- f(mean, u_k) and
    P <- F_k P F_k^T + Q_k.  It relies on two properties shared by all models:
    the yaw increment does not depend on the pose, and the move, the lever and the noise
    depend on the pose only through its heading, as a rotation of the position
    components.  So the K segments are compounded once in the frame of a pose's starting
    heading (:func:`compound_segments`, the same for every pose) and turned into each
    pose's heading (:func:`apply_frame`): O(K + N) work instead of O(K N) (the KTH ute's
    control messages outnumber its scans eightfold).  With ``with_jacobian`` the
    compounded Jacobian A_0 (N, 3, 3) is returned too.
    """
    if np.shape(dts)[0] == 1:          # nothing to compound: the model on every heading costs less
        return _one_segment(config, poses, covariances, controls, dts, with_jacobian)
    frame = compound_segments(config, controls, dts)
    if frame is None:
        identity = np.broadcast_to(np.eye(3), covariances.shape).copy()
        return (poses, covariances, identity) if with_jacobian else (poses, covariances)
    return apply_frame(frame, poses, covariances, with_jacobian)


def _one_segment(config: MotionConfig, poses: np.ndarray, covariances: np.ndarray, controls: np.ndarray,
                 dts: np.ndarray, with_jacobian: bool):
    """:func:`integrate_segments` of one segment, the model evaluated on the N headings (the
    seed scenario's every step: one control per scan)."""
    segment, moves = SEGMENT_PARTS[config.model]
    factors = segment(config, calibrated(config, controls)[:, None, :], np.asarray(dts, dtype=float)[:, None])
    (dx, dy, dyaw), lever, Q = moves(config, factors, poses[None, :, 2] + 0.0)          # (1, N)
    new = poses.copy()
    new[:, 0] += dx[0]
    new[:, 1] += dy[0]
    new[:, 2] += np.zeros(1) + dyaw[:, 0]
    cov = Q[0] + 0.0           # + 0.0: the zero lever's signed zeros
    if covariances.any():
        cov = _through_lever(covariances, np.stack([lever[0][0], lever[1][0]], axis=-1)) + cov
    if not with_jacobian:
        return new, cov
    jacobian = np.zeros((poses.shape[0], 3, 3))
    jacobian[:, 0, 0] = jacobian[:, 1, 1] = jacobian[:, 2, 2] = 1.0
    jacobian[:, 0, 2], jacobian[:, 1, 2] = lever[0][0], lever[1][0]
    return new, cov, jacobian


def apply_frame(frame: SegmentFrame, poses: np.ndarray, covariances: np.ndarray, with_jacobian: bool = False):
    """(f(X), P_K[, A_0]) of poses (N, 3) with covariances P_0 (N, 3, 3) moved by ``frame``,
    turned into each pose's heading."""
    c, sin = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    new = poses.copy()
    new[:, 0] += c * frame.dx - sin * frame.dy
    new[:, 1] += sin * frame.dx + c * frame.dy
    new[:, 2] += frame.yaw
    lever = frame.lever
    total = np.stack([c * lever[0] - sin * lever[1], sin * lever[0] + c * lever[1]], axis=-1)   # (N, 2)
    cov = _turned(frame.noise, c, sin)
    # A zero P_0 (every flush right after a filter step) gives zero through the lever.
    if covariances.any():
        cov += _through_lever(covariances, total)
    if not with_jacobian:
        return new, cov
    jacobian = np.zeros((poses.shape[0], 3, 3))
    jacobian[:, 0, 0] = jacobian[:, 1, 1] = jacobian[:, 2, 2] = 1.0
    jacobian[:, :2, 2] = total
    return new, cov, jacobian


def _turned(M: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """T M T^T (N, 3, 3) of a symmetric M (3, 3), T the rotation by each heading (cos ``c``,
    sin ``s``, (N,)) of the position components; the result exactly symmetric."""
    a, b, e = M[0, 0], 0.5 * (M[0, 1] + M[1, 0]), M[1, 1]
    d, f, g = 0.5 * (M[0, 2] + M[2, 0]), 0.5 * (M[1, 2] + M[2, 1]), M[2, 2]
    cc, ss, cs = c * c, s * s, c * s
    out = np.empty(c.shape + (3, 3))
    out[:, 0, 0] = cc * a - 2.0 * cs * b + ss * e
    out[:, 1, 1] = ss * a + 2.0 * cs * b + cc * e
    out[:, 0, 1] = out[:, 1, 0] = cs * (a - e) + (cc - ss) * b
    out[:, 0, 2] = out[:, 2, 0] = c * d - s * f
    out[:, 1, 2] = out[:, 2, 1] = s * d + c * f
    out[:, 2, 2] = g
    return out


# The two groups of motion noise: what drives the distance travelled (speed, translation)
# and what drives the turning (steering or yaw rate, heading, rotation).  Every model's
# G Q G^T is a sum of terms quadratic in one group's standard deviations, so scaling a
# group's variances by a scales its share of the covariance by a, exactly.
TRANSLATION_STDS = ("sigma_speed", "sigma_speed_relative", "odometry_translation_std",
                    "odometry_translation_per_meter")
ROTATION_STDS = ("sigma_steering", "sigma_steering_relative", "sigma_heading", "odometry_rotation_std",
                 "odometry_rotation_per_radian", "odometry_rotation_per_meter")
RELATIVE_STDS = ("sigma_speed_relative", "sigma_steering_relative")
# A relative std configured at zero gives its learned scale this unit, where learning starts
# (a fraction of the control; a zero would leave nothing to scale).  Wide on purpose: a
# filter whose turning noise is too wide tracks, less precisely, until the learner narrows
# it (and the warm-up replay filters the start again), one too narrow loses the heading
# in the first turn the command misstates and the learner then learns from a lost
# filter (MRCLAM Dataset 9, docs/RESULTS.md: 0.1 and 0.3 lose it, 0.5 and 1.0 do not).
RELATIVE_UNIT = 0.5


def shape_groups(config: MotionConfig) -> tuple[tuple[str, ...], ...]:
    """The groups of motion noise whose variances motion_shape scales one by one.

    A controlled model's noise is the speed's and the turning's, each a constant part and a
    part relative to the control (four groups): a robot that drives straight most of the
    time and turns now and then has a small constant turning noise and a large relative
    one.  The odometry model's per-metre and per-radian stds add to its per-step std, not
    to its variance, so its covariance splits into translation and rotation only.
    """
    if config.uses_odometry:
        return TRANSLATION_STDS, ROTATION_STDS
    return ("sigma_speed",), ("sigma_steering", "sigma_heading"), ("sigma_speed_relative",), \
        ("sigma_steering_relative",)


def shape_basis(config: MotionConfig) -> MotionConfig:
    """``config`` with every relative std configured at zero at RELATIVE_UNIT: the noise the
    learned group scales multiply (the odometry model has no relative stds)."""
    zero = {name: RELATIVE_UNIT for name in RELATIVE_STDS if getattr(config, name) == 0.0}
    return replace(config, **zero) if zero and not config.uses_odometry else config


def scaled_groups(config: MotionConfig, groups: tuple[tuple[str, ...], ...], scales) -> MotionConfig:
    """``config`` with group k's noise variances times scales[k]: its covariance is sum_k scales[k] Q_k."""
    return replace(config, **{name: getattr(config, name) * float(np.sqrt(scale))
                              for group, scale in zip(groups, scales) for name in group})


def scaled_noise(config: MotionConfig, translation: float = 1.0, rotation: float = 1.0) -> MotionConfig:
    """``config`` with the translation group's noise variances times ``translation`` and the
    rotation group's times ``rotation``: its covariance is translation Q_T + rotation Q_R."""
    if translation == 1.0 and rotation == 1.0:
        return config
    return scaled_groups(config, (TRANSLATION_STDS, ROTATION_STDS), (translation, rotation))


def step_jitter(config: MotionConfig) -> np.ndarray:
    """Diagonal covariance added once per filter step so that (T) is never degenerate (read-only)."""
    return _jitter(config.position_jitter, config.heading_jitter)


@lru_cache(maxsize=16)
def _jitter(position: float, heading: float) -> np.ndarray:
    jitter = np.diag([position ** 2, position ** 2, heading ** 2])
    jitter.setflags(write=False)
    return jitter
