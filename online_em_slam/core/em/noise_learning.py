"""Noise parameters learned online by the same EM (docs/METHOD.md
"Noise learned online").

The observation noise R (sigma_r, sigma_b, rho), the mixture weights and
outlier scales, the range-dependent range noise sigma_r(r) = a + b r, the serial
correlation of a landmark's errors (serial_correlation.py) and one scale s on
the motion noise are parameters of the same HMM as the map, so the
filter's E-step estimates them too.  Each filter step turns the posterior
particles into *sufficient statistics* of these parameters; the statistics are
averaged by stochastic approximation (S <- S + gamma_n (s_t - S),
gamma_n = n^-alpha) and the M-step below maps the averages to parameter values,
held between a floor and a ceiling.  The estimator uses them after a warm-up.

Observation statistics, per associated observation p with innovations
nu_ip = y_p - h(xi_i, thetabar_k) under the posterior particles (weights w_i):

    E_p   = sum_i w_i (sum_c r_ipc / s_c) nu_ip nu_ip^T (n_k - 1) / n_k             (E)

r_ipc the responsibility of mixture component c (scale s_c), n_k the landmark's
observation count.  The innovation is predictive (thetabar_k has not seen y_p
yet), so its second moment is R plus the map's uncertainty seen through h,
about R / (n_k - 1) for an estimate that averages n_k - 1 observations, so
R (1 + 1 / (n_k - 1)): the factor takes the map's share out, or R would absorb
the map's uncertainty (:func:`map_share`).
The pose's uncertainty needs no term: averaging over the posterior particles
is the E-step's expectation over the pose (mean outer product plus spread).

Motion statistic (M), per scan at t: the pose predicted open loop over the
last L filter steps from the posterior at t - L, x_pred = xbar_t + C with
C = sum_k Phi(t, k) c_k the compounded motion residuals c_k = f(xbar_{k-1}) - xbar_k
of section 6, gives the scan's prediction error nu = nubar_t - H_x C.  Its
covariance is K + s G, G = H_x Q_L H_x^T the motion noise over the window at
scale 1 and K = H_x Phi P_{t-L} Phi^T H_x^T + R (1 + 1/(n_k - 1)) the rest, so

    s = sum_t (nu^T W nu - tr(W K)) / sum_t tr(W G)                           (M)

(W = S^-1 G S^-1).  A prediction error is not pulled towards the scale the
filter assumed (EM's posterior residuals are, and approach the truth by a
fraction per pass only: one step's motion noise is small next to the pose's
uncertainty, so most of its information is missing).
"""
from __future__ import annotations

import math
from dataclasses import replace
from functools import cached_property

import numpy as np
from scipy.optimize import brentq
from scipy.special import digamma

from ..models.angles import wrap_angle
from ..config import ObservationNoiseConfig, SensorConfig, SlamConfig
from .step import FilterStepData
from ..models.motion import ROTATION_STDS, TRANSLATION_STDS, scaled_noise, step_jitter
from ..models.observation import (component_precision_weight, information_noise, inv_det_2x2, mahalanobis_2d,
                                  noise_covariance, noise_loglik, student_t_weight)
from .averages import StochasticAverage, batch_step_sizes
from .motion_noise import MotionWindow, absolute_error, prediction_statistic, ratio_error
from .motion_gains import MotionGains, gain_statistic, move_towards
from .observed_information import motion_residual
from .serial_correlation import PreviousInnovations, pair_sample, pose_free, serial_correlation, whitened
from ..filter.particles import weighted_pose_mean

MOTION_QUANTITIES = frozenset({"motion_scale", "motion_gains"})
OBSERVATION_QUANTITIES = frozenset({"range", "bearing", "correlation", "mixture", "dof", "range_growth",
                                    "serial_correlation"})
# Range bins of the sigma_r(r) = a + b r fit, over [0, min(max_range, RANGE_BIN_REACH)]
# (farther observations share the last bin): the bins only weigh, their means are exact.
RANGE_BINS, RANGE_BIN_REACH = 16, 100.0
# Largest change of the motion scale in use per filter step, in log: a factor 9 takes 110 steps.
MAX_SCALE_RATE = 0.02
# Its bounds on the ratio, by numpy's exp as they always were (math.exp may round differently).
_SCALE_RATIO = (float(np.exp(-MAX_SCALE_RATE)), float(np.exp(MAX_SCALE_RATE)))


class RangeBins:
    """Per range bin, the stochastic average of (r, r^2, e_r^2).

    E[e_r^2] = E[(a + b r)^2] = a^2 + 2ab E[r] + b^2 E[r^2] holds exactly in every
    bin, whatever its width, so the averages do not depend on the values of
    (a, b) at the time they were taken; the bins only let the fit weigh near and
    far observations by their own variance.
    """

    def __init__(self, max_range: float, alpha: float) -> None:
        self.edges = np.linspace(0.0, min(max_range, RANGE_BIN_REACH), RANGE_BINS + 1)[1:-1]
        self.counts = np.zeros(RANGE_BINS, dtype=np.int64)          # observations blended in per bin
        self.values = np.zeros((RANGE_BINS, 3))                     # the averages (rows with count 0: none yet)
        self.alpha = alpha

    def blend(self, ranges: np.ndarray, squared: np.ndarray) -> None:
        """One scan's observations: per bin, its mean of (r, r^2, e_r^2) as one batch of
        :class:`StochasticAverage` (the first batch replaces the empty average)."""
        index = np.searchsorted(self.edges, ranges)
        order = np.argsort(index, kind="stable")                    # a bin's observations together, in their order
        r = ranges[order]
        bins, sizes, sums = _group_sums(index[order], np.array([r, r * r, squared[order]]))
        sample = sums / sizes[:, None]                              # np.mean: the sum over the count
        counts = self.counts[bins]
        gamma = batch_step_sizes(counts, sizes, self.alpha)
        old = self.values[bins]
        self.values[bins] = np.where((counts == 0)[:, None], sample, old + gamma[:, None] * (sample - old))
        self.counts[bins] = counts + sizes

    def table(self) -> tuple[np.ndarray, np.ndarray]:
        """(weights n_j^alpha (K,), means (K, 3)) of the bins that have data; n^alpha is
        the effective sample size of an average with step sizes n^-alpha."""
        full = self.counts > 0
        return self.counts[full].astype(float) ** self.alpha, self.values[full]


def _group_sums(index: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(groups (K,), sizes (K,), sums (K, Q)) of ``values`` (Q, n, rows contiguous) by the sorted
    group ``index`` (n,).

    Each sum is np.add.reduce of a contiguous run of a row: numpy's pairwise summation of
    the group's values in their order, so sum / size is bit for bit np.mean of the group.
    """
    starts = [0, *(np.flatnonzero(index[1:] != index[:-1]) + 1).tolist()]
    ends = starts[1:] + [index.size]
    sums = np.array([np.add.reduce(values[:, s:e], axis=1) for s, e in zip(starts, ends)])
    return index[starts], np.subtract(ends, starts), sums


def range_noise_fit(counts: np.ndarray, means: np.ndarray, a: float, b: float, free: tuple[bool, bool],
                    iterations: int = 30) -> tuple[float, float]:
    """(a, b) of sigma_r(r) = a + b r by weighted least squares of the bins' mean squared
    range residuals against range (:class:`RangeBins`), ``free`` saying which may move.

    Residuals rho_j = a^2 + 2ab E_j[r] + b^2 E_j[r^2] - E_j[e^2], weights
    n_j^alpha / v_j^2 (a squared Gaussian residual has variance 2 v^2), damped
    Gauss-Newton with the weights renewed at every iteration (iteratively
    reweighted: its fixed point is the maximum-likelihood one).
    """
    free = np.array(free, dtype=bool)
    params = np.array([a, b], dtype=float)
    if counts.size == 0 or not free.any():
        return a, b
    if free[0] and not free[1] and b == 0.0 and a > 0.0 and np.all(np.isfinite(means)):
        return _constant_range_noise_fit(counts, means[:, 2], a, b, iterations)
    for _ in range(iterations):
        weights = counts / np.maximum(_range_variance(means, params), 1e-300) ** 2
        cost = _range_cost(means, weights, params)
        step = _gauss_newton_step(means, weights, params, free)
        if np.all(np.abs(step) <= 1e-9 * np.abs(params) + 1e-15):
            break                                         # converged (the averages move slowly)
        for _ in range(10):                               # backtrack: keep the cost decreasing
            trial = params + step
            if trial[0] > 0 and trial[1] >= 0 and _range_cost(means, weights, trial) <= cost * (1 + 1e-12):
                break
            step = 0.5 * step
        else:
            break
        params = trial
    return float(params[0]), float(params[1])


def _constant_range_noise_fit(counts: np.ndarray, squared: np.ndarray, a: float, b: float,
                              iterations: int) -> tuple[float, float]:
    """:func:`range_noise_fit` of a alone with b = 0 (the default: range_growth not learned),
    in scalars where the general one has arrays, with the same floating-point operations.

    With b = 0 (and finite means) every bin's variance a^2 + 2ab E[r] + b^2 E[r^2] is
    exactly a^2 and the Jacobian's column 2 (a + b E[r]) exactly 2a; the sums over bins stay
    the same BLAS dot products, and the 1x1 solve is LAPACK's one division.  (Solving for a
    in closed form would give the same a up to rounding, not bit for bit.)
    """
    for _ in range(iterations):
        var = a * a
        floor = max(var, 1e-300)
        weights = counts / (floor * floor)                  # counts / max(v, 1e-300)^2 (numpy squares by x * x)
        rho = var - squared
        cost = float(weights @ rho ** 2)
        J = np.full(squared.size, 2.0 * a)
        G = float(J @ (weights * J))
        G = G + 1e-12 * max(G, 1e-300)                      # the ridge of _gauss_newton_step
        step = -(float(J @ (weights * rho)) / G) if G != 0.0 else 0.0   # singular: no step, as LinAlgError
        if abs(step) <= 1e-9 * abs(a) + 1e-15:
            break                                           # converged (b's step is 0)
        for _ in range(10):                                 # backtrack: keep the cost decreasing
            trial = a + step
            if trial > 0 and float(weights @ (trial * trial - squared) ** 2) <= cost * (1 + 1e-12):
                break
            step = 0.5 * step
        else:
            break
        a, b = trial, b + 0.0
    return float(a), float(b)


def _range_variance(means: np.ndarray, params: np.ndarray) -> np.ndarray:
    """E_j[(a + b r)^2] per bin."""
    a, b = params
    return a * a + 2.0 * a * b * means[:, 0] + b * b * means[:, 1]


def _range_cost(means: np.ndarray, weights: np.ndarray, params: np.ndarray) -> float:
    return float(weights @ (_range_variance(means, params) - means[:, 2]) ** 2)


def _gauss_newton_step(means: np.ndarray, weights: np.ndarray, params: np.ndarray, free: np.ndarray) -> np.ndarray:
    """-(J^T W J)^-1 J^T W rho on the free parameters; J_j = 2 (a + b E[r], a E[r] + b E[r^2])."""
    a, b = params
    J = 2.0 * np.stack([a + b * means[:, 0], a * means[:, 0] + b * means[:, 1]], axis=1)[:, free]
    rho = _range_variance(means, params) - means[:, 2]
    G = J.T @ (weights[:, None] * J)
    step = np.zeros(2)
    ridge = 1e-12 * max(np.trace(G), 1e-300)       # all observations in one bin: b is not identified
    try:
        step[free] = -np.linalg.solve(G + ridge * np.eye(G.shape[0]), J.T @ (weights * rho))
    except np.linalg.LinAlgError:
        pass
    return step


def student_t_dof(statistic: float, low: float, high: float) -> float:
    """The dof maximising the expected complete-data log-likelihood of the Gamma(dof/2, dof/2)
    precision scales, given statistic = E[log tau - tau] (<= -1): the root of
    1 + log(dof/2) - psi(dof/2) + statistic = 0, within [low, high].

    log(v/2) - psi(v/2) falls from +inf to 0 as v grows, so the root is unique.
    """
    def score(log_dof: float) -> float:
        half = 0.5 * math.exp(log_dof)
        return 1.0 + math.log(half) - float(digamma(half)) + statistic

    lo, hi = math.log(low), math.log(high)
    if score(lo) <= 0.0:
        return low
    if score(hi) >= 0.0:
        return high                                  # the tails are no heavier than a Gaussian's
    return float(math.exp(brentq(score, lo, hi, xtol=1e-10)))


def map_share(n_obs: np.ndarray) -> np.ndarray:
    """(n_k - 1) / n_k (P,): the part of the innovation's second moment R (1 + 1/(n_k - 1)) that is R.

    A factor rather than subtracting R / (n_k - 1) with the current estimate of R: while
    that is still a wrong start (9x in variance, say) the difference can go negative
    for landmarks seen a few times, and the first, heavily weighted statistics would
    pin R to its floor.
    """
    m = np.maximum(np.asarray(n_obs, dtype=float) - 1.0, 1.0)
    return m / (m + 1.0)


def map_uncertainty(R: np.ndarray, n_obs: np.ndarray) -> np.ndarray:
    """H Sigma_k H^T ~ R / (n_k - 1) (P, 2, 2): the landmark's estimate averages its earlier
    observations, seen through h.

    Taken from the learned R rather than from the M-step's Sigma_k, which is
    built with the R in use: while that is still the wrong starting value
    (10 times too large, say), its map term would swamp the residuals.
    """
    return R / np.maximum(np.asarray(n_obs, dtype=float) - 1.0, 1.0)[:, None, None]


def pose_jacobian_from(H: np.ndarray, pose: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """dh/dX (P, 2, 3) from dh/dtheta (P, 2, 2) at base pose ``pose`` (observation.pose_jacobian
    without the landmarks): dh/dp = -dh/dtheta, the sensor lever arm, -1 on the bearing's yaw."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    lever = np.array([-s * sensor.offset_x - c * sensor.offset_y, c * sensor.offset_x - s * sensor.offset_y])
    J = np.empty(H.shape[:-1] + (3,))
    J[..., :2] = -H
    J[..., 2] = -(H @ lever)
    J[..., 1, 2] -= 1.0
    return J


def _latent(noise: ObservationNoiseConfig, nu: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """noise_loglik's latent variable (..., P, C) without its log-likelihood (the statistics do not
    use it), and the Student-t's d2 = nu^T S^-1 nu (..., P) for its tail statistic (else None).

    ``S`` (P, 2, 2) broadcasts against ``nu`` (..., P, 2): the Student-t's d2 then takes one
    inverse per observation, not one per particle (elementwise the same numbers); the other
    models get S at nu's shape, as noise_loglik always had it.
    """
    if noise.model == "student_t":
        d2, _ = mahalanobis_2d(nu, S)
        return student_t_weight(d2, noise.dof)[..., None], d2
    return noise_loglik(noise, nu, np.broadcast_to(S, nu.shape + (2,)))[1], None


def _clip(x: float, low: float, high: float) -> float:
    """float(np.clip(x, low, high)) of one number without a ufunc call: numpy's order and ties
    (max with low, then min with high; on a tie x stays, NaN stays), which max/min keep."""
    return float(min(max(x, low), high))


class _UsedObservations:
    """The step's observations that inform the noise (``use``) and what the statistics take
    of them, computed once: ranges (P,), counts n_k (P,), innovations nu (N, P, 2), Jacobians
    H (N, P, 2, 2), their R (P, 2, 2) under the current estimate ``noise`` and the map term
    R / (n_k - 1) (P, 2, 2); ``scan`` their posterior means at the mean ``pose``."""

    def __init__(self, data: FilterStepData, n_obs: np.ndarray, use: np.ndarray, R: np.ndarray,
                 pose: np.ndarray, sensor: SensorConfig, noise: ObservationNoiseConfig) -> None:
        self.ranges, self.n_obs = data.y[use, 0], n_obs[use]
        self.nu, self.H = data.nu[:, use], data.H[:, use]
        self.R = R
        self.map_term = map_uncertainty(R, self.n_obs)
        self._mean_of = (data.weights, pose, sensor, noise)

    @cached_property
    def scan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(posterior-mean innovations nubar (P, 2), pose Jacobians H_x (P, 2, 3) at the mean pose,
        the noise model's precision factors at nubar (P,)): shared by the motion and serial statistics."""
        w, pose, sensor, noise = self._mean_of
        nu, latent = self._mean_latent
        H = np.einsum("n,npij->pij", w, self.H)
        return nu, pose_jacobian_from(H, pose, sensor), component_precision_weight(noise, latent)

    @cached_property
    def _mean_latent(self) -> tuple[np.ndarray, np.ndarray]:
        """(posterior-mean innovations nubar (P, 2), the noise model's latent variables at them (P, C))."""
        w, _, _, noise = self._mean_of
        nu = np.einsum("n,npi->pi", w, self.nu)
        return nu, _latent(noise, nu, self.R + self.map_term)[0]

    @cached_property
    def variance_factor(self) -> np.ndarray:
        """The factor on R of each observation's noise variance (P,), for the motion statistic's
        K: under the mixture the scale of the likelier component (exactly 1 for an inlier),
        otherwise 1 / the precision factor.  Not the precision factor's inverse under the
        mixture: an inlier with some responsibility for the outlier component would count
        more variance than it has, and the statistic, which subtracts K, would learn a
        motion scale 5 % low (docs/RESULTS.md)."""
        noise = self._mean_of[3]
        if noise.model != "mixture":
            return 1.0 / self.scan[2]
        return np.asarray(noise.mixture_scales, dtype=float)[np.argmax(self._mean_latent[1], axis=-1)]


class NoiseLearner:
    """Online EM statistics of the noise and the learned :class:`ObservationNoiseConfig` and motion scale.

    ``update`` once per filter step; ``noise_config()`` and ``motion_scale()``
    are what the estimator uses (the configured values until warmed up).
    """

    def __init__(self, config: SlamConfig) -> None:
        self.config = config
        self.settings = config.noise_learning
        learn = set(self.settings.learn) if self.settings.enabled else set()
        if config.noise.model != "mixture":
            learn.discard("mixture")                     # nothing to learn in one Gaussian
        if config.noise.model != "student_t":
            learn.discard("dof")
        self.learn = learn
        self.observations = StochasticAverage(self.settings.step_size_exponent)
        self.serial = StochasticAverage(self.settings.step_size_exponent)    # consecutive innovations' moments
        self._previous = PreviousInnovations()
        self.motion = StochasticAverage(self.settings.motion_step_size_exponent)
        self.window = MotionWindow(self.settings.motion_window + 1)
        self._jitter_key, self._jitter = None, None
        self.range_bins = RangeBins(config.sensor.max_range, self.settings.step_size_exponent)
        self.estimate = config.noise                     # current M-step values
        self.scale_estimate = 1.0
        self.scale_in_use = 1.0
        self._motion_warm = False
        # The calibration of the motion input (motion_gains.py): the gains in use.
        self.gains = (MotionGains(self.settings.motion_step_size_exponent, self.settings.motion_window)
                      if "motion_gains" in learn else None)
        self.sensitivities = np.zeros((self.settings.motion_window + 1, 3, 2))
        self.gains_in_use = np.array([config.motion.translation_gain, config.motion.rotation_gain])
        self.gains_estimate, self.gain_errors = self.gains_in_use.copy(), np.full(2, math.inf)
        self._gain_warm = np.zeros(2, dtype=bool)        # each gain in use once known to the tolerance
        self._motion_config = (None, None)                # (gains, the motion config with them)
        self._start = config.noise                       # in use until warm: configured, or restored
        self._in_use = config.noise

    def start_from(self, noise: ObservationNoiseConfig, motion_scale: float, motion_gains=None) -> None:
        """Start from values learned earlier (a loaded map file) instead of the configured
        ones: in use at once, then replaced by this run's estimates once they are warm."""
        if not self.learn:
            return
        observation = bool(self.learn & OBSERVATION_QUANTITIES)
        if observation:
            self.estimate = self._start = self._in_use = noise
        if "motion_scale" in self.learn:
            low, high = self.settings.motion_scale_limits
            self.scale_estimate = self.scale_in_use = _clip(motion_scale, low, high)
        if self.gains is not None and motion_gains is not None:
            self.gains_in_use = np.clip(np.asarray(motion_gains, dtype=float), *self.settings.motion_gain_limits)
            self.gains_estimate = self.gains_in_use.copy()

    def saved_values(self) -> dict[str, np.ndarray] | None:
        """The values in use for a map file (None when nothing is learned)."""
        if not self.learn:
            return None
        noise = self._in_use
        values = {"noise": np.array([noise.sigma_range, noise.range_growth, noise.sigma_bearing, noise.rho,
                                     self.scale_in_use]),
                  "noise_mixture": np.array([noise.mixture_weights, noise.mixture_scales], dtype=float)}
        if noise.model == "student_t":
            values["noise_dof"] = np.array(noise.dof)
        if any(noise.serial_correlation):
            values["noise_serial"] = np.array(noise.serial_correlation, dtype=float)
        return values

    # ------------------------------------------------------------ what the estimator uses
    @property
    def all_in_use(self) -> bool:
        """Every learned quantity has replaced its configured value (nothing learned: False)."""
        observation = not (self.learn & OBSERVATION_QUANTITIES) or self.observation_noise_warm
        motion = "motion_scale" not in self.learn or self.motion_scale_warm
        gains = self.gains is None or bool(self._gain_warm.any())       # the warm-up is re-filtered with them
        return bool(self.learn) and observation and motion and gains

    @property
    def observation_noise_warm(self) -> bool:
        return self.observations.count >= self.settings.warmup_observations and self.observations.value is not None

    @property
    def motion_scale_warm(self) -> bool:
        """Warmed up and known to ``motion_scale_tolerance`` (relative standard error); then for good
        (set where the statistic changes, :meth:`_update_motion`)."""
        return self._motion_warm

    def motion_scale_error(self) -> float:
        """Relative standard error of the motion scale's estimate (inf before it is positive):
        :func:`ratio_error` x sqrt(motion_window), since consecutive windows share all but one
        step of motion noise (their triangular autocorrelation sums to the window's length)."""
        if self.motion.value is None:
            return math.inf
        return math.sqrt(self.settings.motion_window) * ratio_error(self.motion.value, self.motion.squared_weights)

    @property
    def _observation_noise_settled(self) -> bool:
        """(M) holds R in K and the filter's pose spread P_{t-L}, which follows the R in use: it
        waits until the learned R has been in use for a warm-up (twice the warm-up), or a
        wrong starting R (whose wide or narrow posteriors the spreads still show) would
        stay in the motion statistic's average."""
        settled = self.observations.count >= 2 * self.settings.warmup_observations
        return settled or not (self.learn & OBSERVATION_QUANTITIES)

    def noise_config(self) -> ObservationNoiseConfig:
        """The observation noise for R, the likelihood and the gates."""
        return self._in_use

    def motion_scale(self) -> float:
        """Factor on the motion noise covariance (1 until warmed up or when not learned)."""
        return self.scale_in_use

    @property
    def learns_gains(self) -> bool:
        return self.gains is not None

    def motion_config(self):
        """The motion config to integrate with: the configured one with the gains in use
        (the motion scale multiplies the covariance it gives)."""
        key = tuple(self.gains_in_use)
        if self._motion_config[0] != key:
            self._motion_config = (key, replace(self.config.motion, translation_gain=float(self.gains_in_use[0]),
                                                rotation_gain=float(self.gains_in_use[1])))
        return self._motion_config[1]

    def gains_known(self) -> np.ndarray:
        """The gains' estimates where known to the tolerance, else the gains in use (2,)."""
        return np.where(self._gain_warm, self.gains_estimate, self.gains_in_use)

    # ------------------------------------------------------------ E-step
    def update(self, data: FilterStepData, n_obs: np.ndarray, ids: np.ndarray | None = None) -> None:
        """Blend in one filter step's statistics and redo the M-step of the noise.

        ``n_obs`` (P,): observation counts of the observed landmarks (this one
        included); ``ids`` (P,) their landmark ids (default: their rows).
        """
        if not self.learn:
            return
        n_obs = np.asarray(n_obs)
        weighed = information_noise(self._in_use)
        configured, R_filter = self._configured_R(data, weighed)
        use = (n_obs >= self.settings.min_landmark_observations) & configured
        pose = weighted_pose_mean(data.particles, data.weights)
        # The statistics take the same observations under the same (current) estimate; once
        # warm that is the noise in use, whose R (elementwise in the ranges) the filter made
        # already unless it weighed it for serially correlated errors.
        used = None
        if use.any():
            made = self.estimate is self._in_use and weighed is self._in_use
            R = R_filter[use] if made else noise_covariance(self.estimate, data.y[use, 0])
            used = _UsedObservations(data, n_obs, use, R, pose, self.config.sensor, self.estimate)
        if self.learn & MOTION_QUANTITIES:
            self._update_motion(data, used, pose)        # every step: silence is part of the motion
        if "serial_correlation" in self.learn and used is not None:
            self._update_serial(data.step, used, (data.rows if ids is None else np.asarray(ids))[use])
        if self.learn & OBSERVATION_QUANTITIES and data.rows.size:
            statistics = self._observation_statistics(data, used)
            if statistics is not None:
                sample, ranges, squared = statistics
                self.observations.blend(sample, ranges.size)
                self.range_bins.blend(ranges, squared)
                self.estimate = self._observation_m_step(self.observations.value)
                self._in_use = self.estimate if self.observation_noise_warm else self._start

    def _observation_statistics(self, data: FilterStepData, used: _UsedObservations | None):
        """(the step's mean of [E_bb, rho term, tail statistics], ranges, E_rr), from (E), over the
        ``used`` observations (landmarks seen often enough, the configured R)."""
        if used is None:
            return None
        # Latent variables under the latest estimate (the E-step of online EM runs at the
        # current parameter, also while the filter still warms up).
        noise = self.estimate
        ranges, nu, R, map_term, w = used.ranges, used.nu, used.R, used.map_term, data.weights
        latent, d2 = _latent(noise, nu, R + map_term)                                 # (N, P, C)
        outer = nu[..., :, None] * nu[..., None, :] * map_share(used.n_obs)[:, None, None]
        E = np.einsum("n,np,npij->pij", w, component_precision_weight(noise, latent), outer)  # (E), (P, 2, 2)
        a, b = noise.sigma_range, noise.range_growth
        sample = np.concatenate([
            [E[:, 1, 1].mean(), (a * E[:, 0, 1] / (a + b * ranges)).mean()],     # rho scales with sigma_r(r)
            self._tail_statistics(noise, w, latent, outer, R, d2)])
        if not (np.all(np.isfinite(sample)) and np.all(np.isfinite(E[:, 0, 0]))):
            return None
        return sample, ranges, E[:, 0, 0]

    @staticmethod
    def _tail_statistics(noise, w: np.ndarray, latent: np.ndarray, outer: np.ndarray, R: np.ndarray,
                         d2: np.ndarray | None) -> np.ndarray:
        """The statistics of the tails' parameters, averaged over the scan's observations.

        Mixture: mean responsibilities r_c and r_c q, q = tr(R^-1 outer) / 2 (weights and
        outlier scales).  Student-t: E[log tau - tau | nu] with tau | nu ~ Gamma((dof + 2)/2,
        (dof + d2)/2), so E[log tau] = psi((dof + 2)/2) - log((dof + d2)/2) (the dof), d2 (N, P)
        the innovations' nu^T S^-1 nu.
        """
        if noise.model == "student_t":
            log_tau = digamma(0.5 * noise.dof + 1.0) - np.log(0.5 * (noise.dof + d2))
            return np.array([np.einsum("n,np->p", w, log_tau - latent[..., 0]).mean()])
        R_inv, _ = inv_det_2x2(R)
        q = 0.5 * np.einsum("pij,npji->np", R_inv, outer)                             # tr(R^-1 outer) / 2
        return np.concatenate([np.einsum("n,npc->pc", w, latent).mean(axis=0),
                               np.einsum("n,npc,np->pc", w, latent, q).mean(axis=0)])

    def _configured_R(self, data: FilterStepData, weighed: ObservationNoiseConfig) -> tuple[np.ndarray, np.ndarray]:
        """(observations whose R is the filter's, from ``weighed``, the noise in use as the filter
        weighs it (P,), that R (P, 2, 2)); those with their own range_std / bearing_std carry a
        known noise and say nothing about R."""
        expected = noise_covariance(weighed, data.y[:, 0])
        if np.array_equal(data.R, expected):        # the usual case: isclose holds wherever == does
            return np.ones(expected.shape[:-2], dtype=bool), expected
        return np.all(np.isclose(data.R, expected, rtol=1e-9, atol=1e-15), axis=(-1, -2)), expected

    def _update_serial(self, step: int, used: _UsedObservations, ids: np.ndarray) -> None:
        """Pair the scan's whitened pose-free innovations with the same landmarks' in the scan
        before and blend their moments (serial_correlation.py)."""
        if ids.size < 2:
            return
        nu, H_x, scale = used.scan
        residual, cov, shared = pose_free(nu, used.R + used.map_term, H_x, used.map_term)
        z = whitened(residual, cov, scale)
        previous, paired = self._previous.pair(step, ids, z)
        if previous.shape[0] and np.all(np.isfinite(previous)) and np.all(np.isfinite(z[paired])):
            share = shared[paired] / np.diagonal(cov[paired], axis1=-2, axis2=-1) * scale[paired, None]
            self.serial.blend(pair_sample(previous, z[paired], share), previous.shape[0])

    def _step_jitter(self) -> np.ndarray:
        """step_jitter of the motion config, made again only when its jitter values change."""
        motion = self.config.motion
        key = (motion.position_jitter, motion.heading_jitter)
        if key != self._jitter_key:
            self._jitter_key, self._jitter = key, step_jitter(motion)
        return self._jitter

    def _update_motion(self, data: FilterStepData, used: _UsedObservations | None, pose: np.ndarray) -> None:
        """Push the step into the window; at a scan of known landmarks, blend (M) of the window."""
        scale = self.motion_scale()
        jitter = self._step_jitter()
        dev = data.particles - pose
        dev[:, 2] = wrap_angle(dev[:, 2])
        self.window.append(motion_residual(data.motion_mean, pose), data.motion_jacobian,
                           (data.motion_cov - jitter) / scale, jitter, np.einsum("n,ni,nj->ij", data.weights, dev, dev))
        if self.gains is not None:
            self.sensitivities[:-1] = self.sensitivities[1:]
            self.sensitivities[-1] = data.motion_gain_sensitivity
        if not self.window.full or used is None:
            return
        if self.gains is not None:
            self._update_gains(used)
        if "motion_scale" not in self.learn or not self._observation_noise_settled:
            return
        sample = prediction_statistic(self.window.steps, *self._scan_terms(used), weight_scale=self.scale_in_use)
        if sample is None:
            return
        a, b = sample
        self.motion.blend(np.array([a, b, a * a, a * b, b * b]))         # the moments for motion_scale_error
        low, high = self.settings.motion_scale_limits
        self.scale_estimate = _clip(self.motion.value[1] / self.motion.value[0], low, high)
        known = (self.motion_scale_error() <= self.settings.motion_scale_tolerance
                 or self._scale_beyond_limit(low, high))
        self._motion_warm = self._motion_warm or (self.motion.count >= self.settings.warmup_steps and known)
        if self._motion_warm:
            # Move towards the estimate by at most MAX_SCALE_RATE (log) per step: the pose
            # spreads in (M) come from the filter under the scale in use; no jumps.
            ratio = _clip(self.scale_estimate / self.scale_in_use, *_SCALE_RATIO)
            self.scale_in_use = float(self.scale_in_use * ratio)

    def _scale_beyond_limit(self, low: float, high: float) -> bool:
        """The statistic puts the scale beyond a limit by more than two standard errors: the
        constrained estimate is the limit, known (a scale the data put at or below 0 has no
        relative error, and would otherwise never come into use)."""
        raw = self.motion.value[1] / self.motion.value[0]
        limit = low if raw < low else high if raw > high else None
        if limit is None:
            return False
        error = math.sqrt(self.settings.motion_window) * absolute_error(self.motion.value, self.motion.squared_weights,
                                                                        limit)
        return bool(abs(raw - limit) > 2.0 * error)

    def _update_gains(self, used: _UsedObservations) -> None:
        """Blend (G) of the window (motion_gains.py); move the gains in use once they are known."""
        z = gain_statistic(self.window.steps, self.sensitivities, *self._scan_terms(used), self.scale_in_use,
                           self.gains_in_use)
        if z is None:
            return
        self.gains.blend(z)
        result = self.gains.estimate()
        if result is None:
            return
        estimate, self.gain_errors = result
        self.gains_estimate = np.clip(estimate, *self.settings.motion_gain_limits)
        if self.gains.count >= self.settings.warmup_steps:
            self._gain_warm |= self.gain_errors <= self.settings.motion_gain_tolerance
        target = np.where(self._gain_warm, self.gains_estimate, self.gains_in_use)
        self.gains_in_use = move_towards(self.gains_in_use, target, _SCALE_RATIO)

    @staticmethod
    def _scan_terms(used: _UsedObservations):
        """(H_x (P, 2, 3), posterior mean innovation (P, 2), noise covariance (P, 2, 2)) of the scan.

        The noise is the learned R times each observation's variance factor (an outlier's
        wider) plus the map term H Sigma H^T.
        """
        nu, H_x, _ = used.scan
        return H_x, nu, used.R * used.variance_factor[:, None, None] + used.map_term

    # ------------------------------------------------------------ M-step
    def _observation_m_step(self, stats: np.ndarray) -> ObservationNoiseConfig:
        """Noise values from the averaged statistics, each within its floor and ceiling."""
        s, noise = self.settings, self.estimate
        a, b = noise.sigma_range, noise.range_growth
        free = ("range" in self.learn, "range_growth" in self.learn)
        if any(free):
            a, b = range_noise_fit(*self.range_bins.table(), a, b, free)
            a, b = _clip(a, *s.sigma_range_limits), _clip(b, *s.range_growth_limits)
        sb = noise.sigma_bearing
        if "bearing" in self.learn:
            sb = _clip(math.sqrt(max(stats[0], 0.0)), *s.sigma_bearing_limits)
        rho = noise.rho
        if "correlation" in self.learn:
            bound = s.correlation_limit * a * sb
            rho = _clip(stats[1], -bound, bound)
        else:
            rho = _clip(rho, -0.999 * a * sb, 0.999 * a * sb)            # stays valid as a, sb move
        values = dict(sigma_range=a, range_growth=b, sigma_bearing=sb, rho=rho)
        if "mixture" in self.learn:
            values.update(self._mixture_m_step(stats[2:]))
        if "dof" in self.learn:
            values["dof"] = student_t_dof(float(stats[2]), *s.dof_limits)
        if "serial_correlation" in self.learn and self.serial.value is not None:
            values["serial_correlation"] = serial_correlation(self.serial.value, s.serial_correlation_limit)
        return replace(noise, **values)

    def _mixture_m_step(self, stats: np.ndarray) -> dict:
        """Weights = mean responsibilities; outlier scales = E[r_c q] / E[r_c] (component 0 keeps scale 1)."""
        s = self.settings
        c = stats.size // 2
        resp, q = stats[:c], stats[c:]
        outlier_w = np.clip(resp[1:], *s.mixture_weight_limits)
        outlier_w *= min(1.0, 0.5 / max(outlier_w.sum(), 1e-300))      # the inlier keeps at least half
        scales = np.asarray(self.estimate.mixture_scales, dtype=float).copy()
        seen = resp[1:] > 1e-9
        scales[1:][seen] = np.clip(q[1:][seen] / resp[1:][seen], *s.mixture_scale_limits)
        weights = np.concatenate([[1.0 - outlier_w.sum()], outlier_w])
        return {"mixture_weights": tuple(float(v) for v in weights / math.fsum(weights)),
                "mixture_scales": (1.0,) + tuple(float(v) for v in scales[1:])}

    # ------------------------------------------------------------ reporting
    def learned(self) -> dict:
        """Current estimates, whether the estimator uses them, and the counts behind them."""
        noise = self.estimate
        return {"enabled": bool(self.learn), "learning": sorted(self.learn),
                "observations": int(self.observations.count), "motion_steps": int(self.motion.count),
                "observation_noise_in_use": self.observation_noise_warm and bool(self.learn & OBSERVATION_QUANTITIES),
                "motion_scale_in_use": "motion_scale" in self.learn and self.motion_scale_warm,
                "sigma_range": noise.sigma_range, "sigma_bearing": noise.sigma_bearing, "rho": noise.rho,
                "range_growth": noise.range_growth, "model": noise.model, "dof": noise.dof,
                "serial_correlation": list(noise.serial_correlation),
                "mixture_weights": list(noise.mixture_weights), "mixture_scales": list(noise.mixture_scales),
                "motion_scale": self.scale_estimate, "motion_scale_error": _finite_or_none(self.motion_scale_error()),
                "motion_gains": self.gains_estimate.tolist(), "motion_gains_in_use": self._gain_warm.tolist(),
                "motion_gains_error": [_finite_or_none(float(e)) for e in self.gain_errors]}

    def parameters(self) -> dict:
        """The values in use as flat node parameters (noise.*, motion.* standard deviations),
        the form of a parameter file: the motion scale s is folded into the stds (x sqrt(s)); the
        learned gains are motion.translation_gain and rotation_gain."""
        noise = self._in_use
        values = {"noise.model": noise.model, "noise.sigma_range": noise.sigma_range,
                  "noise.sigma_bearing": noise.sigma_bearing, "noise.rho": noise.rho,
                  "noise.range_growth": noise.range_growth, "noise.dof": noise.dof,
                  "noise.serial_correlation": [float(v) for v in noise.serial_correlation],
                  "noise.mixture_weights": [float(v) for v in noise.mixture_weights],
                  "noise.mixture_scales": [float(v) for v in noise.mixture_scales]}
        motion = scaled_noise(self.config.motion, self.motion_scale(), self.motion_scale())
        values.update({f"motion.{name}": getattr(motion, name) for name in TRANSLATION_STDS + ROTATION_STDS})
        if self.gains is not None:
            values.update({"motion.translation_gain": float(self.gains_in_use[0]),
                           "motion.rotation_gain": float(self.gains_in_use[1])})
        return values


def _finite_or_none(value: float) -> float | None:
    """A value for /diagnostics and metrics.json, which have no infinity."""
    return value if math.isfinite(value) else None
