"""The settings of the noise learned online (the ``noise_learning`` section of SlamConfig)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .config_fields import check_fields, check_length, check_range, param, param_info

LEARNABLE_NOISE = ("range", "bearing", "correlation", "mixture", "dof", "range_growth", "serial_correlation",
                   "serial_length", "motion_scale", "motion_gains", "motion_gain_in_place", "motion_delay",
                   "motion_drift", "motion_shape")


@dataclass
class NoiseLearningConfig:
    """Online EM estimation of the noise parameters (docs/METHOD.md "Noise learned online", core/em/noise/).

    learn: the quantities estimated, a subset of ``LEARNABLE_NOISE``: ``range``
        (sigma_range), ``bearing`` (sigma_bearing), ``correlation`` (rho),
        ``mixture`` (weights and outlier scales; only with ``noise.model: mixture``),
        ``dof`` (the Student-t's degrees of freedom; only with ``noise.model: student_t``),
        ``range_growth`` (sigma_r(r) = sigma_range + range_growth r; not by
        default: without range-dependent noise it trades off against
        sigma_range), ``serial_correlation`` (how alike a landmark's
        observation errors are from one scan to the next: real detectors repeat
        their errors, so consecutive observations inform less than independent
        ones), ``serial_length`` (with it: how fast that likeness decays as the
        sensor's view of the landmark changes, noise.serial_length), ``motion_scale`` (one factor on the whole motion noise
        covariance) and ``motion_shape`` (instead: one factor per noise group, for
        a controlled model the speed's and the turning's constant and relative
        parts, so the starting values' ratio does not stay; docs/METHOD.md
        "Motion shape").
    step_size_exponent: gamma_n = n^-exponent (n counts observations) of the
        observation-noise statistics; below 1 the statistics computed under
        the first, wrong noise values are forgotten.
    motion_step_size_exponent: the same for the motion scale's statistic (n
        counts scans).  That statistic is a prediction error, valid whatever
        scale the filter used, so there is nothing to forget: 1 averages all
        of it (below 1 follows a motion noise that changes, e.g. with terrain).
    warmup_observations / warmup_steps: the learned observation noise is used
        after this many observations, the motion scale after this many scans.
    motion_scale_tolerance: ... and once the motion scale's relative standard
        error is below this: one scan says little about the motion noise, and a
        few hundred scans' estimate can still be several times off.
    replay_warmup / max_replay_inputs: the warm-up ran under the configured
        (possibly wrong) noise, and the map's frame set then stays; once every
        learned quantity is in use, the estimator restarts at its initial pose
        and filters the warm-up's inputs (at most ``max_replay_inputs``) again
        with the learned noise as the starting values, once.
    replay_growth: the values in use while the later inputs were filtered
        keep moving after the warm-up replay (a motion gain decided then at a
        transient of its statistic, MRCLAM), and the map keeps what was filtered
        under them; the kept inputs are filtered again from the start, under
        the values learned from all of them, each time they have grown by this
        factor: batch EM's E-step again at geometrically spaced times, g / (g - 1)
        passes over the inputs in all (5 at 1.25, config/mrclam.yaml).
    replay_on_calibration: with motion_gains learned, a gain that comes into
        use before that (the calibration of the motion input) has the inputs so
        far filtered again from the start with it, once: a heading error made
        at a wrong turning gain grows with every turn, and the noise learned
        from a filter that ran at it is learned from that error.
    motion_window: filter steps over which the pose is predicted open loop for
        the motion scale's statistic (one step's motion noise is small next to
        the pose's uncertainty; L steps' is not).
    min_landmark_observations: observations of a landmark seen fewer times
        (this one included) are not used: its estimate is still the inverted
        first observation and its residual says little about R.
    *_limits: (floor, ceiling) of each learned value; correlation_limit bounds
        |rho| / (sigma_range sigma_bearing); serial_correlation_limit is the
        ceiling of the serial correlation (its floor is 0); mixture_weight_limits bound each
        outlier component's weight.  The limits' ranges keep the learned values
        inside what ObservationNoiseConfig / MotionConfig accept.
    """

    enabled: bool = param(False, doc="Learn the noise online by EM (noise_learning.learn); the learned values "
                          "are used once warmed up and shown on /diagnostics.")
    learn: tuple[str, ...] = param(("range", "bearing", "correlation", "mixture", "dof", "serial_correlation",
                                    "motion_scale"),
                                   choices=LEARNABLE_NOISE, doc="Quantities learned: any of range, bearing, "
                                   "correlation, mixture (with noise.model mixture), dof (with noise.model "
                                   "student_t), range_growth, serial_correlation, serial_length (with serial_correlation: its "
                                   "decay with the viewpoint's change, noise.serial_length), motion_scale, "
                                   "motion_shape (a "
                                   "scale per motion noise group: speed and turning, constant and relative "
                                   "to the control, instead of motion_scale), motion_gains (the "
                                   "calibration of the motion input: motion.translation_gain, "
                                   "rotation_gain), motion_gain_in_place (with motion_gains: a third gain, "
                                   "motion.rotation_in_place_gain, for turns in place; not the default of "
                                   "any data set, docs/RESULTS.md), motion_delay (the drive's dead time "
                                   "motion.control_delay, by the gains' statistic, with them or alone), "
                                   "motion_drift (the unicycle's turn per metre driven, motion.turn_per_meter, "
                                   "the same way). To learn nothing set enabled false.")
    step_size_exponent: float = param(0.7, 0.5, 1.0, lo_open=True, doc="Step size gamma_n = n^-exponent of the "
                                      "noise statistics.")
    motion_step_size_exponent: float = param(1.0, 0.5, 1.0, lo_open=True, doc="Step size exponent of the motion "
                                             "scale's statistic; 1 averages it all (it is valid under any scale).")
    warmup_observations: int = param(200, 0, 10 ** 9, doc="Observations before the learned observation noise "
                                     "is used.")
    warmup_steps: int = param(50, 0, 10 ** 9, doc="Scans (motion statistics) before the learned motion scale "
                              "is used.")
    motion_scale_tolerance: float = param(0.5, 0.0, 10.0, lo_open=True, doc="The learned motion scale is used "
                                          "once its relative standard error is below this (and warmup_steps "
                                          "have passed): a short run's estimate can be several times off.")
    replay_warmup: bool = param(True, doc="Once every learned quantity is in use, filter the warm-up's inputs "
                                "again from the start with the learned noise (once; the pose may jump then), "
                                "unless the data cannot tell the learned values from those the warm-up "
                                "began under (a chi-square test at 0.95; docs/METHOD.md).")
    replay_on_calibration: bool = param(True, doc="With motion_gains learned: once a motion gain comes into "
                                        "use before the warm-up replay, filter the inputs so far again from the "
                                        "start with it (once; the pose may jump then).")
    replay_growth: float = param(0.0, 0.0, 100.0, doc="After the warm-up replay, filter the kept inputs "
                                 "again from the start each time they have grown by this factor since the last "
                                 "replay started (0: never; otherwise above 1; g / (g - 1) passes over the inputs "
                                 "in all). A fleet replays all its robots' inputs together, as they grow.")
    max_replay_inputs: int = param(100000, 0, 10 ** 7, doc="Inputs kept for the warm-up replay (per robot "
                                   "in fleet mode); a longer warm-up is not replayed.")
    motion_window: int = param(10, 1, 1000, doc="Filter steps over which the pose is predicted open loop for "
                               "the motion scale's statistic.")
    min_landmark_observations: int = param(5, 1, 10 ** 6, doc="Observations of landmarks seen fewer times (this "
                                           "one included) do not inform R.")
    sigma_range_limits: tuple[float, float] = param((0.01, 10.0), 0.0, 100.0, lo_open=True, doc="Floor and "
                                                    "ceiling of the learned sigma_range (m), floor <= ceiling.")
    sigma_bearing_limits: tuple[float, float] = param((0.001, 0.5), 0.0, math.pi, lo_open=True, doc="Floor and "
                                                      "ceiling of the learned sigma_bearing (rad), floor <= ceiling.")
    range_growth_limits: tuple[float, float] = param((0.0, 0.5), 0.0, 1.0, doc="Floor and ceiling of the "
                                                     "learned range_growth, floor <= ceiling.")
    correlation_limit: float = param(0.9, 0.0, 0.99, doc="Bound on |rho| / (sigma_range sigma_bearing) when "
                                     "learned.")
    serial_correlation_limit: float = param(0.95, 0.0, 0.99, doc="Ceiling of the learned serial_correlation "
                                            "(each observation informs at least (1 - c) / (1 + c) of an "
                                            "independent one).")
    mixture_weight_limits: tuple[float, float] = param((0.001, 0.5), 0.0, 0.5, lo_open=True, doc="Floor and "
                                                       "ceiling of each learned outlier weight, floor <= ceiling.")
    mixture_scale_limits: tuple[float, float] = param((2.0, 1000.0), 1.0, 1e6, lo_open=True, doc="Floor and "
                                                      "ceiling of each learned outlier scale, floor <= ceiling.")
    dof_limits: tuple[float, float] = param((3.0, 100.0), 0.5, 1e4, doc="Floor and ceiling of the learned "
                                            "Student-t degrees of freedom, floor <= ceiling.")
    motion_scale_limits: tuple[float, float] = param((0.01, 100.0), 0.0, 1e4, lo_open=True, doc="Floor and "
                                                     "ceiling of the learned motion noise scale (factor on the "
                                                     "motion covariance), floor <= ceiling.")

    motion_gain_limits: tuple[float, float] = param((0.25, 4.0), 0.1, 10.0, doc="Floor and ceiling of the "
                                                    "learned motion gains (motion.translation_gain, rotation_gain, "
                                                    "rotation_in_place_gain), floor <= ceiling.")
    motion_gain_tolerance: float = param(0.03, 0.0, 1.0, lo_open=True, doc="The learned motion gains are used "
                                         "once their standard errors are below this, or once the estimate is "
                                         "three standard errors from the gain in use (and warmup_steps have "
                                         "passed).")
    motion_delay_limits: tuple[float, float] = param((0.0, 1.0), 0.0, 5.0, doc="Floor and ceiling (s) of the "
                                                     "learned dead time of the drive (motion.control_delay), "
                                                     "floor <= ceiling; it is used by the rule of "
                                                     "motion_gain_tolerance, read in seconds.")
    motion_drift_limits: tuple[float, float] = param((-0.2, 0.2), -1.0, 1.0, doc="Floor and ceiling (rad/m) "
                                                     "of the learned turn per metre driven "
                                                     "(motion.turn_per_meter), floor <= ceiling; it is used by "
                                                     "the rule of motion_gain_tolerance, read in rad/m.")
    _LIMITS = ("sigma_range_limits", "sigma_bearing_limits", "range_growth_limits", "mixture_weight_limits",
               "mixture_scale_limits", "dof_limits", "motion_scale_limits",
               "motion_gain_limits", "motion_delay_limits", "motion_drift_limits")

    def validate(self, prefix: str = "noise_learning") -> None:
        if isinstance(self.learn, str):
            raise ValueError(f"{prefix}.learn = {self.learn!r} must be a list of names of {', '.join(LEARNABLE_NOISE)}")
        if "motion_gain_in_place" in self.learn and "motion_gains" not in self.learn:
            raise ValueError(f"{prefix}.learn: motion_gain_in_place is a third motion gain, learned with motion_gains")
        if 0.0 < self.replay_growth <= 1.0:
            raise ValueError(f"{prefix}.replay_growth = {self.replay_growth} must be 0 (off) or above 1")
        if "serial_length" in self.learn and "serial_correlation" not in self.learn:
            raise ValueError(f"{prefix}.learn: serial_length is the serial correlation's decay, learned with "
                             "serial_correlation")
        for name in self._LIMITS:
            check_length(f"{prefix}.{name}", getattr(self, name), 2, " (floor, ceiling)")
        check_fields(self, prefix)
        for name in self._LIMITS:          # each floor <= its ceiling
            floor, ceiling = getattr(self, name)
            check_range(f"{prefix}.{name}", ceiling, float(floor), param_info(self.__dataclass_fields__[name]).hi)
