"""The motion between filter steps: control segments queued until a scan or a pose query
needs them, then compounded into the Gaussian transition (T) in one vectorised call
(models/motion.py ``integrate_segments``; control messages, 40 Hz on the KTH ute,
outnumber scans).  The weighted mean pose's own transition since the last filter step
(f, F, Q: the observed M-step's linearisation track) rides along as one more row.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np

from ..config import MotionConfig
from ..models import motion as motion_models
from ..models.angles import wrap_angle


# The shift of the command stream (s) whose effect gives d pose / d control_delay.
DELAY_STEP = 1e-4
# The change of the turn per metre (rad/m) whose effect gives d pose / d turn_per_meter.
DRIFT_STEP = 1e-6


class PendingMotion:
    """Queued segments (``controls``, ``dts``) and the track since the last filter step:
    ``pose`` (3,), ``cov`` (3, 3), ``jacobian`` (3, 3) and ``sensitivity`` (3, G), d pose / d
    the G gains the noise learner learns (none: G = 0)."""

    def __init__(self, pose: np.ndarray, n_gains: int = 0) -> None:
        self.n_gains = n_gains
        self.controls: list[np.ndarray] = []
        self.dts: list[float] = []
        # The track's covariance from each noise group (learner.motion_parts; sized at first use).
        self.cov_parts = np.zeros((0, 3, 3))
        self.reset_track(pose)

    def reset_track(self, pose: np.ndarray) -> None:
        """The track restarts at ``pose`` (a filter step, a new pose)."""
        self.pose = pose.copy()
        self.jacobian = np.eye(3)
        self.cov = np.zeros((3, 3))
        self.cov_parts = np.zeros_like(self.cov_parts)
        self.sensitivity = np.zeros((3, self.n_gains))

    def queue(self, control: np.ndarray, dt: float) -> None:
        self.controls.append(control)
        self.dts.append(dt)

    def flush(self, config: MotionConfig, gains: tuple[str, ...], means: np.ndarray, covs: np.ndarray,
              drops: Counter, parts: tuple | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """The particles' transitions (``means`` (N, 3), ``covs`` (N, 3, 3)) moved by the queued
        segments under ``config``, and the track with them; None when nothing is queued, or
        when the result is not finite (counted in ``drops``: the last finite state stays)."""
        if not self.dts:
            return None
        controls, dts = np.array(self.controls), np.array(self.dts)
        poses = np.vstack([means, self.pose])
        covs = np.concatenate([covs, self.cov[None]])
        mean, cov, F = motion_models.integrate_segments(config, poses, covs, controls, dts, with_jacobian=True)
        sensitivity = (self._gain_sensitivity(config, gains, controls, dts, mean[-1], F[-1]) if gains
                       else self.sensitivity)
        cov_parts = self.cov_parts
        if parts is not None:            # the track's covariance split by noise group (motion shape learned)
            if cov_parts.shape[0] != len(parts):
                self.cov_parts = cov_parts = np.zeros((len(parts), 3, 3))
            cov_parts = np.stack([motion_models.integrate_segments(part, self.pose[None], self.cov_parts[k][None],
                                                                   controls, dts)[1][0]
                                  for k, part in enumerate(parts)])
        self.controls.clear()
        self.dts.clear()
        if not (np.isfinite(mean).all() and np.isfinite(cov).all() and np.isfinite(sensitivity).all()):
            # Never let one step poison the estimate: keep the last finite state.
            drops["non_finite_prediction"] += 1
            return None
        mean[:, 2] = wrap_angle(mean[:, 2])
        self.pose, self.cov, self.cov_parts = mean[-1], cov[-1], cov_parts
        self.jacobian = F[-1] @ self.jacobian
        self.sensitivity = sensitivity
        return mean[:-1], cov[:-1]

    def _gain_sensitivity(self, config: MotionConfig, gains: tuple[str, ...], controls: np.ndarray, dts: np.ndarray,
                          moved: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
        """d track mean / d ``gains`` (names of MotionConfig's) since the last filter step (3, G):
        the earlier segments' carried by this flush's Jacobian, plus this flush's, by a forward
        difference of the motion integration (``moved``: the track's mean after it)."""
        pose = self.pose[None]
        D = np.empty((3, len(gains)))
        for j, name in enumerate(gains):
            nudged, controls_j, dts_j, step = _nudged(config, name, controls, dts)
            D[:, j] = (motion_models.integrate_segments(nudged, pose, np.zeros((1, 3, 3)), controls_j, dts_j)[0][0]
                       - moved) / step
        return jacobian @ self.sensitivity + D


def _nudged(config: MotionConfig, name: str, controls: np.ndarray, dts: np.ndarray) -> tuple:
    """(config, controls, dts, step): the motion with the gain ``name`` a small step further; the
    dead time's step shifts the segments instead (:func:`delayed_segments`)."""
    if name == motion_models.DELAY:
        return (config, *delayed_segments(controls, dts, DELAY_STEP), DELAY_STEP)
    # A gain's step is relative; the turn per metre may be 0, so its step is absolute.
    step = DRIFT_STEP if name == motion_models.DRIFT else 1e-6 * getattr(config, name)
    return replace(config, **{name: getattr(config, name) + step}), controls, dts, step


def delayed_segments(controls: np.ndarray, dts: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """The segments (controls (K, 2), dts (K,)) as they would run ``delta`` s later: the first control
    (the one in effect when they start) runs ``delta`` longer at the start, and as much is cut from
    the end, so they span the same time."""
    lengths = np.array(dts, dtype=float)
    lengths[0] += delta                     # one segment, not two: the integration's own steps
    lengths = np.diff(np.concatenate([[0.0], np.minimum(np.cumsum(lengths), dts.sum())]))
    keep = lengths > 0.0
    return controls[keep], lengths[keep]
