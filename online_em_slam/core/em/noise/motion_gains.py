"""The calibration of the motion input learned online: a gain on the speed and one on the turning.

Wheel radii, track widths and commanded velocities are rarely what the data
sheet says: a robot that turns 0.6 times its commanded yaw rate (UTIAS MRCLAM,
Dataset 9) makes a heading error that grows with every turn, which no noise
model explains.  The gains kappa = (translation_gain, rotation_gain) of the
motion model (models/motion.py, ``calibrated``; with ``motion_gain_in_place``
also rotation_in_place_gain, for a robot whose controllers deliver a turn in
place and a turn while driving in different shares: 1.0 and 0.6 on Dataset 9;
with ``motion_drift`` the unicycle's turn_per_meter, with ``motion_delay`` the drive's
dead time, both added rather than multiplied, as they may start at 0)
are parameters of the HMM like the map, and the same window as the motion
scale's statistic (M) estimates them: the pose predicted open loop over the
last L filter steps,
x_pred(kappa) = xbar_t + C(kappa), gives the scan's prediction error

    nu(kappa) = nu_t - B_t (kappa - kappa_t),   B_t = H_x sum_k Phi(t, k) D_k          (G)

to first order, D_k = d f_k / d kappa the step's sensitivity to the gains and
kappa_t the gains in use when step t was filtered.  With nu ~ N(0, S_t) at the
true gains, the maximum-likelihood kappa of all scans solves the normal
equations N kappa = h, averaged over scans:

    N = mean_t B_t^T S_t^-1 B_t,   h = mean_t B_t^T S_t^-1 (nu_t + B_t kappa_t).

A gain no window has excited (a robot that never turns in place) has no row in N:
it stays where it is, and the others are solved without it; while the informed
ones are not separable (N singular) all stay.
"""
from __future__ import annotations

import numpy as np

from ...models.motion import DELAY, DRIFT, GAIN_NAMES
from .averages import StochasticAverage
from .motion_noise import MotionSteps, block_diagonal, compound

# Largest change per filter step of a learned dead time in use (s) and of a turn per metre (rad/m):
# additive rates, as both may start at 0.
MAX_DELAY_RATE = 0.005
MAX_DRIFT_RATE = 0.001
ADDITIVE_RATES = {DELAY: MAX_DELAY_RATE, DRIFT: MAX_DRIFT_RATE}
MAX_CONDITION = 1e6                   # N (unit diagonal) of the informed gains solved only below this
# A learned gain replaces the one in use once they differ by this many standard errors.
REJECTION = 3.0


def transported(F: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """sum_k Phi(t, k) terms_k for steps k = 0..L-1 of Jacobians F (L, 3, 3), terms (L, 3, m):
    each step's effect carried to the window's end (Phi(t, k) = F_{L-1} ... F_{k+1})."""
    total = np.zeros(terms.shape[1:])
    for k in range(F.shape[0]):
        total = F[k] @ total + terms[k]
    return total


def gain_statistic(steps: MotionSteps, D: np.ndarray, pose_jacobian: np.ndarray, innovation: np.ndarray,
                   noise_cov: np.ndarray, scale: float, gains: np.ndarray) -> np.ndarray | None:
    """z = (N_t (G, G) flattened, h_t (G,)) of (G) for the scan at the window's end.

    ``steps`` as for motion_noise.prediction_statistic (Q over the scale in use), ``D``
    (L, 3, G) each step's sensitivity of the mean pose to the gains, ``gains`` the gains
    in use (G,), ``scale`` the motion scale in use.
    """
    C, Q, J, Phi = compound(steps[1:])
    Hx = pose_jacobian.reshape(-1, 3)
    nu = innovation.reshape(-1) - Hx @ C
    B = Hx @ transported(steps.F[1:], D[1:])
    S = Hx @ (Phi @ steps.P[0] @ Phi.T + J + scale * Q) @ Hx.T + block_diagonal(noise_cov)
    try:
        S_inv_B = np.linalg.solve(S, B)
    except np.linalg.LinAlgError:
        return None
    N = B.T @ S_inv_B
    h = S_inv_B.T @ (nu + B @ gains)
    z = np.concatenate([N.ravel(), h])
    return z if np.isfinite(z).all() and N.trace() > 0 else None


class MotionGains:
    """The average of (G)'s normal equations for ``n_gains`` gains; the gains, their standard errors."""

    def __init__(self, alpha: float, window: int, n_gains: int = 2) -> None:
        self.average = StochasticAverage(alpha)
        self.window = window              # consecutive windows share all but one step: variance x L
        self.n_gains = n_gains

    @property
    def count(self) -> int:
        return self.average.count

    def blend(self, z: np.ndarray) -> None:
        self.average.blend(z)

    def estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(gains (G,), their standard errors (G,)) from the averages: NaN and an infinite error
        for a gain no window excited; None while the informed ones are not separable."""
        if self.average.value is None:
            return None
        g = self.n_gains
        N, h = self.average.value[:g * g].reshape(g, g), self.average.value[g * g:]
        informed = np.diag(N) > 0.0
        if not informed.any():
            return None
        N, h = N[np.ix_(informed, informed)], h[informed]
        d = np.sqrt(np.diag(N))
        if not np.linalg.cond(N / np.outer(d, d)) < MAX_CONDITION:
            return None
        N_inv = np.linalg.inv(N)
        variance = self.window * self.average.squared_weights * np.diag(N_inv)
        estimate, error = np.full(g, np.nan), np.full(g, np.inf)
        estimate[informed], error[informed] = N_inv @ h, np.sqrt(np.maximum(variance, 0.0))
        return estimate, error


def known(estimate: np.ndarray, in_use: np.ndarray, errors: np.ndarray, tolerance: float) -> np.ndarray:
    """Which gains to use (G,): known to ``tolerance``, or the data reject the gain in use by
    more than REJECTION standard errors (a command's calibration can be far off, 0.6 on MRCLAM
    Dataset 9, and yet not known to the tolerance in a whole run: the regimes of turning in
    place and while driving differ)."""
    return (errors <= tolerance) | (np.abs(estimate - in_use) > REJECTION * errors)


def calibration_names(learn) -> tuple[str, ...]:
    """The motion.* calibration values ``learn`` (noise_learning.learn) has learned, in the order of
    (G)'s columns: the gains (the in-place one with motion_gain_in_place), the turn per metre, the
    dead time."""
    gains = GAIN_NAMES if "motion_gain_in_place" in learn else GAIN_NAMES[:2]
    return ((gains if "motion_gains" in learn else ()) + ((DRIFT,) if "motion_drift" in learn else ())
            + ((DELAY,) if "motion_delay" in learn else ()))


def calibration_limits(names: tuple[str, ...], settings) -> np.ndarray:
    """(floor, ceiling) of each calibration value ``names`` (2, G), from NoiseLearningConfig ``settings``."""
    limits = {DELAY: settings.motion_delay_limits, DRIFT: settings.motion_drift_limits}
    return np.array([limits.get(name, settings.motion_gain_limits) for name in names]).T


def move_towards(in_use: np.ndarray, target: np.ndarray, ratio: tuple[float, float],
                 rates: np.ndarray | None = None) -> np.ndarray:
    """Each gain moved towards its target by at most the factor ``ratio`` allows; those with an
    additive rate (``rates`` (G,) > 0: a dead time, a turn per metre, which may start at 0) by at
    most that much."""
    additive = None if rates is None else rates > 0.0
    if additive is None or not additive.any():
        return in_use * np.clip(target / in_use, *ratio)
    moved = in_use + np.clip(target - in_use, -rates, rates)
    scaled = in_use * np.clip(np.divide(target, in_use, out=np.ones_like(target), where=~additive), *ratio)
    return np.where(additive, moved, scaled)

