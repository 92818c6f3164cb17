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

The observation statistics (E) and the dof and mixture M-steps are in observation.py, the
range noise fit in range_fit.py, the serial correlation in serial_correlation.py, the motion
scale's statistic (M) in motion_noise.py; the learner blends them and runs the M-step.
start_difference.py says whether the data tell the learned values from the warm-up's.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ...config import ObservationNoiseConfig, SlamConfig
from ...models.angles import wrap_angle
from ...models.motion import (GAIN_NAMES, ROTATION_STDS, TRANSLATION_STDS, gain, scaled_groups, scaled_noise,
                              shape_basis, shape_groups, step_jitter)
from ...models.observation import information_noise, noise_covariance, sensor_poses, serially_weighed
from ..segment_factors import motion_residual
from ..step import FilterStepData
from .averages import StochasticAverage
from .motion_gains import (ADDITIVE_RATES, MotionGains, calibration_limits, calibration_names, gain_statistic,
                           known, move_towards)
from .motion_noise import (MotionWindow, absolute_error, group_scales, prediction_statistic, ratio_error,
                           shape_statistic)
from .observation import UsedObservations, mixture_m_step, observation_statistics, student_t_dof
from .range_fit import RangeBins, range_noise_fit
from .serial_correlation import SerialStatistic, pose_free, whitened
from .start_difference import WITHOUT_ERROR, differs, gain_scores, motion_scale_score, observation_scores

MOTION_QUANTITIES = frozenset({"motion_scale", "motion_gains", "motion_delay", "motion_drift", "motion_shape"})
# The calibration of the motion input (motion_gains.py): gains, the turn per metre, the drive's dead time.
CALIBRATION = frozenset({"motion_gains", "motion_delay", "motion_drift"})
OBSERVATION_QUANTITIES = frozenset({"range", "bearing", "correlation", "mixture", "dof", "range_growth",
                                    "serial_correlation", "serial_length"})
# Largest change of the motion scale in use per filter step, in log: a factor 9 takes 110 steps.
MAX_SCALE_RATE = 0.02
# Its bounds on the ratio, by numpy's exp (math.exp may round differently).
_SCALE_RATIO = (float(np.exp(-MAX_SCALE_RATE)), float(np.exp(MAX_SCALE_RATE)))


def _clip(x: float, low: float, high: float) -> float:
    """float(np.clip(x, low, high)) of one number without a ufunc call: numpy's order and ties
    (max with low, then min with high; on a tie x stays, NaN stays), which max/min keep."""
    return float(min(max(x, low), high))


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
        self._tails = bool(learn & {"mixture", "dof"})   # the tail statistics' M-steps run
        self.observations = StochasticAverage(self.settings.step_size_exponent)
        self.serial = SerialStatistic(self.settings.step_size_exponent, "serial_length" in learn,
                                      config.noise.serial_turn_length)
        self.motion = StochasticAverage(self.settings.motion_step_size_exponent)
        self.window = MotionWindow(self.settings.motion_window + 1)
        self._jitter_key, self._jitter = None, None
        self.range_bins = RangeBins(config.sensor.max_range, self.settings.step_size_exponent)
        self.estimate = config.noise                     # current M-step values
        self.scale_estimate = 1.0
        self.scale_in_use = 1.0
        self._motion_warm = False
        # The calibration of the motion input (motion_gains.py): the gains in use.
        self.gain_names = calibration_names(learn) if learn & CALIBRATION else GAIN_NAMES[:2]   # none: configured
        self._gain_limits = calibration_limits(self.gain_names, self.settings)
        self._gain_rates = np.array([ADDITIVE_RATES.get(name, 0.0) for name in self.gain_names])
        self.gains = (MotionGains(self.settings.motion_step_size_exponent, self.settings.motion_window,
                                  len(self.gain_names)) if learn & CALIBRATION else None)
        self.gains_in_use = np.array([gain(config.motion, name) for name in self.gain_names])
        self.sensitivities = np.zeros((self.settings.motion_window + 1, 3, len(self.gain_names)))
        self.gains_estimate, self.gain_errors = self.gains_in_use.copy(), np.full(len(self.gain_names), math.inf)
        self._motion_start = (1.0, self.gains_in_use.copy())   # the motion scale and gains the warm-up begins at
        self._gain_warm = np.zeros(len(self.gain_names), dtype=bool)   # each in use once known to the tolerance
        self._motion_config = (None, None)                # (gains and scales, the motion config with them)
        self._weighed = (None, None)                      # (the noise in use, its information_noise)
        self._gains_config_made = (None, None)            # (gains, the configured motion config with them)
        # The motion noise's shape (motion_shape): one scale per noise group (models/motion.py
        # shape_groups: speed and turning, constant and relative, for a controlled model).
        self.shape = "motion_shape" in learn
        self.groups = shape_groups(config.motion)
        self.scales_in_use, self.scales_estimate = np.ones(len(self.groups)), np.ones(len(self.groups))
        self.shape_average = StochasticAverage(self.settings.motion_step_size_exponent)
        self.parts = np.zeros((self.settings.motion_window + 1, len(self.groups), 3, 3))
        self._shape_warm = False
        self._parts_config = (None, None)
        self._start = config.noise                       # in use until warm: configured, or restored
        self._in_use = config.noise
        # While holding, every value in use stays as it is (observation noise, motion scales,
        # gains) and the statistics gather as usual; after, the estimates take over as they are
        # warm.  The warm-up replay (filter/warmup.py) holds the values learned from the warm-up
        # while it filters the warm-up again: learned again from those same observations,
        # restarted from a few, the noise would be counted twice and, against a map fitted to
        # those few under a narrow R, fall below the first pass's estimate (MRCLAM D1 R3:
        # sigma_range 0.11 -> 0.06 m within the replay).
        self.holding = False

    def start_from(self, noise: ObservationNoiseConfig, motion_scale: float, motion_gains=None,
                   motion_scales=None) -> None:
        """Start from values learned earlier (a loaded map file, the warm-up replay) instead of
        the configured ones: in use at once, then replaced by this run's estimates once they are
        warm.  ``motion_scales``: motion_shape's group scales."""
        if not self.learn:
            return
        observation = bool(self.learn & OBSERVATION_QUANTITIES)
        if observation:
            self.estimate = self._start = self._in_use = noise
        if "motion_scale" in self.learn:
            low, high = self.settings.motion_scale_limits
            self.scale_estimate = self.scale_in_use = _clip(motion_scale, low, high)
        if self.shape and motion_scales is not None:
            low, high = self.settings.motion_scale_limits
            self.scales_in_use = np.clip(np.asarray(motion_scales, dtype=float), low, high)
            self.scales_estimate = self.scales_in_use.copy()
        if self.gains is not None and motion_gains is not None:
            self.gains_in_use = np.clip(np.asarray(motion_gains, dtype=float), *self._gain_limits)
            self.gains_estimate = self.gains_in_use.copy()
        self._motion_start = (self.scale_in_use, self.gains_in_use.copy())

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
        if any(noise.serial_length):
            values["noise_serial_length"] = np.array(noise.serial_length, dtype=float)
        return values

    # ------------------------------------------------------------ what the estimator uses
    @property
    def all_in_use(self) -> bool:
        """Every learned quantity has replaced its configured value (nothing learned: False)."""
        observation = not (self.learn & OBSERVATION_QUANTITIES) or self.observation_noise_warm
        motion = ("motion_scale" not in self.learn or self.shape or self.motion_scale_warm) and (
            not self.shape or self._shape_warm)
        gains = self.gains is None or self.calibration_in_use       # the warm-up is re-filtered with them
        return bool(self.learn) and observation and motion and gains

    def differs_from_start(self) -> bool:
        """The data tell the learned values from those the warm-up began under (start_difference.py)."""
        if self.learn & WITHOUT_ERROR:
            return True
        scores = observation_scores(self.learn, self._in_use, self._start, self.observations.squared_weights,
                                    self.serial.average.squared_weights)
        if "motion_scale" in self.learn:
            scores.append(motion_scale_score(self.scale_estimate, self._motion_start[0], self.motion.value,
                                             self.motion.squared_weights, self.settings.motion_window))
        if self.gains is not None:
            scores += gain_scores(self.gains_known(), self._motion_start[1], self.gain_errors)
        return differs(scores)

    @property
    def serial_known(self) -> bool:
        """The serial correlation's decay, when learned, has as many pairs as the observation noise
        has observations when warm (the warm-up replay comes again once it has: warmup.py)."""
        return self.serial.pairs is None or self.serial.pairs.counts.sum() >= self.settings.warmup_observations

    @property
    def calibration_in_use(self) -> bool:
        """A learned motion gain has replaced its configured value."""
        return self.gains is not None and bool(self._gain_warm.any())

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

    def weighed_noise(self) -> ObservationNoiseConfig:
        """information_noise of the noise in use (the likelihood's and the M-step's), made again only
        when the noise in use changes (the filter and the statistics ask for it at every scan)."""
        if self._weighed[0] is not self._in_use:
            self._weighed = (self._in_use, information_noise(self._in_use))
        return self._weighed[1]

    def motion_scale(self) -> float:
        """Factor on the motion noise covariance (1 until warmed up or when not learned; 1 with
        motion_shape, whose two scales the motion config carries)."""
        return 1.0 if self.shape else self.scale_in_use

    def motion_parts(self):
        """With motion_shape: the gains' motion config with only one noise group's noise, per group
        (unit scales), for the track's covariance parts; else None."""
        if not self.shape:
            return None
        base = self._gains_config()
        if self._parts_config[0] is not base:
            basis, unit = shape_basis(base), np.eye(len(self.groups))
            self._parts_config = (base, tuple(scaled_groups(basis, self.groups, row) for row in unit))
        return self._parts_config[1]

    @property
    def gains_learned(self) -> tuple[str, ...]:
        """Names of the motion gains learned (none: ())."""
        return self.gain_names if self.gains is not None else ()

    def motion_config(self):
        """The motion config to integrate with: the configured one with the gains in use
        (the motion scale multiplies the covariance it gives; motion_shape's two scales are in it)."""
        # The arrays' bytes: a cheaper key than their values (asked for at every control message).
        key = (self.gains_in_use.tobytes(), self.scales_in_use.tobytes())
        if self._motion_config[0] != key:
            base = self._gains_config()
            self._motion_config = (key, scaled_groups(shape_basis(base), self.groups, self.scales_in_use)
                                   if self.shape else base)
        return self._motion_config[1]

    def _gains_config(self):
        """The configured motion config with the gains in use (made again only when they change)."""
        key = self.gains_in_use.tobytes()
        if self._gains_config_made[0] != key:
            self._gains_config_made = (key, replace(self.config.motion, **{
                name: float(value) for name, value in zip(self.gain_names, self.gains_in_use)}))
        return self._gains_config_made[1]

    def gains_known(self) -> np.ndarray:
        """The gains' estimates where known to the tolerance, else the gains in use (G,)."""
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
        weighed = self.weighed_noise()
        configured, R_filter = self._configured_R(data, weighed)
        use = (n_obs >= self.settings.min_landmark_observations) & configured
        pose = data.pose_mean()
        # The statistics take the same observations under the same (current) estimate; once
        # warm that is the noise in use, whose R (elementwise in the ranges) the filter made
        # already unless it weighed it for serially correlated errors.
        used = None
        if use.any():
            made = self.estimate is self._in_use and weighed is self._in_use
            R = R_filter[use] if made else noise_covariance(self.estimate, data.y[use, 0])
            used = UsedObservations(data, n_obs, use, R, pose, self.config.sensor, self.estimate)
        if self.learn & MOTION_QUANTITIES:
            self._update_motion(data, used, pose)        # every step: silence is part of the motion
        if "serial_correlation" in self.learn and used is not None:
            self._update_serial(data.step, used, (data.rows if ids is None else np.asarray(ids))[use], pose)
        if self.learn & OBSERVATION_QUANTITIES and data.rows.size:
            # Latent variables under the latest estimate (the E-step of online EM runs at the
            # current parameter, also while the filter still warms up).
            statistics = observation_statistics(self.estimate, data.weights, used, self._tails)
            if statistics is not None:
                sample, ranges, squared = statistics
                self.observations.blend(sample, ranges.size)
                self.range_bins.blend(ranges, squared)
                self.estimate = self._observation_m_step(self.observations.value)
                if not self.holding:
                    self._in_use = self.estimate if self.observation_noise_warm else self._start

    def _configured_R(self, data: FilterStepData, weighed: ObservationNoiseConfig) -> tuple[np.ndarray, np.ndarray]:
        """(observations whose R is the filter's, from ``weighed``, the noise in use as the filter
        weighs it, or each observation's serial correlation (P,), that R (P, 2, 2)); those with
        their own range_std / bearing_std carry a known noise and say nothing about R."""
        expected = (noise_covariance(weighed, data.y[:, 0]) if data.serial is None
                    else serially_weighed(noise_covariance(self._in_use, data.y[:, 0]), data.serial))
        if np.array_equal(data.R, expected):        # the usual case: isclose holds wherever == does
            return np.ones(expected.shape[:-2], dtype=bool), expected
        return np.all(np.isclose(data.R, expected, rtol=1e-9, atol=1e-15), axis=(-1, -2)), expected

    def _update_serial(self, step: int, used: UsedObservations, ids: np.ndarray, pose: np.ndarray) -> None:
        """The scan's whitened pose-free innovations into the serial correlation's statistic
        (serial_correlation.py)."""
        if ids.size < 2:
            return
        nu, H_x, scale = used.scan
        residual, cov, shared = pose_free(nu, used.S, H_x, used.map_term)
        share = shared / np.diagonal(cov, axis1=-2, axis2=-1) * scale[:, None]
        self.serial.update(step, ids, whitened(residual, cov, scale), share, sensor_poses(pose, self.config.sensor))

    def _step_jitter(self) -> np.ndarray:
        """step_jitter of the motion config, made again only when its jitter values change."""
        motion = self.config.motion
        key = (motion.position_jitter, motion.heading_jitter)
        if key != self._jitter_key:
            self._jitter_key, self._jitter = key, step_jitter(motion)
        return self._jitter

    def _update_motion(self, data: FilterStepData, used: UsedObservations | None, pose: np.ndarray) -> None:
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
        if self.shape:
            self.parts[:-1] = self.parts[1:]
            # No motion since the last step (a first scan before any control acts): no parts yet, zero.
            self.parts[-1] = data.motion_cov_parts if data.motion_cov_parts.shape[0] else 0.0
        if not self.window.full or used is None:
            return
        if self.gains is not None:
            self._update_gains(used)
        if self.shape:
            self._update_shape(used)
            return
        if "motion_scale" not in self.learn or not self._observation_noise_settled:
            return
        sample = prediction_statistic(self.window.steps, *used.scan_terms, weight_scale=self.scale_in_use)
        if sample is None:
            return
        a, b = sample
        self.motion.blend(np.array([a, b, a * a, a * b, b * b]))         # the moments for motion_scale_error
        low, high = self.settings.motion_scale_limits
        self.scale_estimate = _clip(self.motion.value[1] / self.motion.value[0], low, high)
        known = (self.motion_scale_error() <= self.settings.motion_scale_tolerance
                 or self._scale_beyond_limit(low, high))
        self._motion_warm = self._motion_warm or (self.motion.count >= self.settings.warmup_steps and known)
        if self._motion_warm and not self.holding:
            # Move towards the estimate by at most MAX_SCALE_RATE (log) per step: the pose
            # spreads in (M) come from the filter under the scale in use; no jumps.
            ratio = _clip(self.scale_estimate / self.scale_in_use, *_SCALE_RATIO)
            self.scale_in_use = float(self.scale_in_use * ratio)

    def _update_shape(self, used: UsedObservations) -> None:
        """Blend the two-scale statistic of the window (motion_noise.shape_statistic); move the
        scales in use towards the estimate once warm."""
        if not self._observation_noise_settled:
            return
        z = shape_statistic(self.window.steps, self.parts, *used.scan_terms, self.scales_in_use)
        if z is None:
            return
        self.shape_average.blend(z)
        m = len(self.groups)
        A, b = self.shape_average.value[:m * m].reshape(m, m), self.shape_average.value[m * m:]
        low, high = self.settings.motion_scale_limits
        self.scales_estimate = group_scales(A, b, low, high, self.scales_estimate)
        self._shape_warm = self._shape_warm or self.shape_average.count >= self.settings.warmup_steps
        if self._shape_warm and not self.holding:
            self.scales_in_use = self.scales_in_use * np.clip(self.scales_estimate / self.scales_in_use, *_SCALE_RATIO)

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

    def _update_gains(self, used: UsedObservations) -> None:
        """Blend (G) of the window (motion_gains.py); move the gains in use once they are known."""
        z = gain_statistic(self.window.steps, self.sensitivities, *used.scan_terms, self.scale_in_use,
                           self.gains_in_use)
        if z is None:
            return
        self.gains.blend(z)
        result = self.gains.estimate()
        if result is None:
            return
        estimate, self.gain_errors = result
        # A gain no window excited (NaN: never turned in place) keeps the one in use.
        self.gains_estimate = np.where(np.isnan(estimate), self.gains_in_use,
                                       np.clip(estimate, *self._gain_limits))
        if self.gains.count >= self.settings.warmup_steps:
            self._gain_warm |= known(self.gains_estimate, self.gains_in_use, self.gain_errors,
                                     self.settings.motion_gain_tolerance)
        if not self.holding:
            target = np.where(self._gain_warm, self.gains_estimate, self.gains_in_use)
            self.gains_in_use = move_towards(self.gains_in_use, target, _SCALE_RATIO, self._gain_rates)

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
            values.update(mixture_m_step(stats[2:], self.estimate.mixture_scales, s))
        if "dof" in self.learn:
            values["dof"] = student_t_dof(float(stats[2]), *s.dof_limits)
        if "serial_correlation" in self.learn:
            values.update(self.serial.values(s.serial_correlation_limit))
        return replace(noise, **values)

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
                "serial_correlation": list(noise.serial_correlation), "serial_length": list(noise.serial_length),
                "mixture_weights": list(noise.mixture_weights), "mixture_scales": list(noise.mixture_scales),
                "motion_scale": self.scale_estimate, "motion_scale_error": _finite_or_none(self.motion_scale_error()),
                "motion_scales": self.scales_estimate.tolist() if self.shape else None,
                "motion_gain_names": list(self.gain_names),   # motion.* parameters: gains, the dead time
                "motion_gains": self.gains_estimate.tolist(), "motion_gains_in_use": self._gain_warm.tolist(),
                "motion_gains_error": [_finite_or_none(float(e)) for e in self.gain_errors]}

    def parameters(self) -> dict:
        """The values in use as flat node parameters (noise.*, motion.* standard deviations),
        the form of a parameter file: the motion scale s is folded into the stds (x sqrt(s)); the
        learned gains are motion.translation_gain, rotation_gain (and rotation_in_place_gain)."""
        noise = self._in_use
        values = {"noise.model": noise.model, "noise.sigma_range": noise.sigma_range,
                  "noise.sigma_bearing": noise.sigma_bearing, "noise.rho": noise.rho,
                  "noise.range_growth": noise.range_growth, "noise.dof": noise.dof,
                  "noise.serial_correlation": [float(v) for v in noise.serial_correlation],
                  "noise.serial_length": [float(v) for v in noise.serial_length],
                  "noise.mixture_weights": [float(v) for v in noise.mixture_weights],
                  "noise.mixture_scales": [float(v) for v in noise.mixture_scales]}
        motion = (scaled_groups(shape_basis(self.config.motion), self.groups, self.scales_in_use) if self.shape
                  else scaled_noise(self.config.motion, self.motion_scale(), self.motion_scale()))
        values.update({f"motion.{name}": getattr(motion, name) for name in TRANSLATION_STDS + ROTATION_STDS})
        if self.gains is not None:
            values.update({f"motion.{name}": float(value) for name, value in zip(self.gain_names, self.gains_in_use)})
        return values


def _finite_or_none(value: float) -> float | None:
    """A value for /diagnostics and metrics.json, which have no infinity."""
    return value if math.isfinite(value) else None
