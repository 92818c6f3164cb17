"""Whether the learned values differ from those the warm-up began under (docs/METHOD.md,
"Noise learned online", warm-up replay).

The warm-up replay filters the warm-up again under the learned values.  When the data cannot
tell those from the values the warm-up ran under (a simulation started at its truth; a Car
Park run restarted from its own noise.yaml still differs, its sigmas 6-8 standard errors
lower at the decision), the second pass draws the first again: on
the seed scenario started at its truth (20 seeds) the replay moved the landmark RMSE by
-0.04 +- 0.12 m and the shape by +0.003 +- 0.004 m, at the price of a second pass over the
warm-up.  Each learned value gives z = (learned - start) / its standard error under the
start value; they differ when sum z^2 exceeds the chi-square quantile at
``START_TEST_PROBABILITY`` of as many degrees of freedom.

Standard errors, from the averages' squared weights q (averages.py: Var(S) = q Var(s)) and
Gaussian errors (heavier tails make the true ones larger, so the test then finds a
difference more often than it should, and replays):

* a standard deviation sigma from squared errors: sigma0 sqrt(q / 2) (Var(e^2) = 2 sigma^4);
* rho from products of range and bearing errors: sqrt(q (sigma_r0^2 sigma_b0^2 + rho0^2));
* a serial correlation c from pairs: (1 - c0^2) sqrt(q) (q of the pairs' average);
* the Student-t's dof: sqrt(q / I(dof0)), I the Fisher information of one bivariate t
  observation about its dof at a known scale (Lange, Little & Taylor 1989;
  :func:`dof_information`); with the scale learned too the true error is larger;
* the motion scale: its standard error around s0 (``motion_noise.absolute_error``, times
  sqrt(motion window) as the learner's own rule);
* a motion gain, dead time or turn per metre: its standard error (``MotionGains``).

Learned quantities without one here (range_growth, mixture, serial_length, motion_shape)
count as differing: their warm-up is replayed as before.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.special import gammaincinv, polygamma

from ...config import ObservationNoiseConfig
from .motion_noise import absolute_error

START_TEST_PROBABILITY = 0.95
# Learned quantities whose standard error is not made here: they always count as differing.
WITHOUT_ERROR = frozenset({"range_growth", "mixture", "serial_length", "motion_shape"})


def chi_square_quantile(probability: float, dof: int) -> float:
    """The value a chi-square variable of ``dof`` degrees of freedom stays below with ``probability``
    (scipy.stats' chi2.ppf, without importing scipy.stats)."""
    return float(2.0 * gammaincinv(0.5 * dof, probability))


def differs(scores: Sequence[float] | None) -> bool:
    """The z-scores (None: a quantity without a standard error) put the learned values apart from
    the start: sum z^2 beyond the chi-square quantile, or a score that is not finite."""
    if scores is None:
        return True
    z = np.asarray(scores, dtype=float)
    if not np.isfinite(z).all():
        return True
    return bool(z.size) and float(z @ z) > chi_square_quantile(START_TEST_PROBABILITY, z.size)


def dof_information(dof: float, dims: int = 2) -> float:
    """Fisher information about the dof of one ``dims``-dimensional Student-t observation, its scale
    known: (psi'(v/2) - psi'((v + p)/2)) / 4 - p (v + p + 4) / (2 v (v + p) (v + p + 2))."""
    v, p = dof, dims
    return float(0.25 * (polygamma(1, 0.5 * v) - polygamma(1, 0.5 * (v + p))) - p * (v + p + 4) / (
        2.0 * v * (v + p) * (v + p + 2)))


def z_score(difference: float, standard_error: float) -> float:
    """difference / standard_error: 0 for no difference, inf for one without a positive error."""
    if difference == 0.0:
        return 0.0
    return difference / standard_error if standard_error > 0.0 else math.inf


def observation_scores(learn: frozenset | set, noise: ObservationNoiseConfig, start: ObservationNoiseConfig,
                       q: float, q_pairs: float) -> list[float]:
    """z of the learned observation noise ``noise`` against ``start``; ``q``, ``q_pairs``: the squared
    weights of the observations' and of the serial pairs' averages."""
    scores = []
    if "range" in learn:
        scores.append(z_score(noise.sigma_range - start.sigma_range, start.sigma_range * math.sqrt(q / 2.0)))
    if "bearing" in learn:
        scores.append(z_score(noise.sigma_bearing - start.sigma_bearing, start.sigma_bearing * math.sqrt(q / 2.0)))
    if "correlation" in learn:
        spread = math.sqrt(q * ((start.sigma_range * start.sigma_bearing) ** 2 + start.rho ** 2))
        scores.append(z_score(noise.rho - start.rho, spread))
    if "dof" in learn:
        information = dof_information(start.dof)        # > 0 to a dof of 1e5; rounding could reach 0
        scores.append(z_score(noise.dof - start.dof, math.sqrt(q / information) if information > 0 else math.inf))
    if "serial_correlation" in learn:
        for c, c0 in zip(noise.serial_correlation, start.serial_correlation):
            scores.append(z_score(c - c0, (1.0 - c0 * c0) * math.sqrt(q_pairs)))
    return scores


def motion_scale_score(s: float, s0: float, moments: np.ndarray, q: float, window: int) -> float:
    """z of the learned motion scale ``s`` against ``s0`` from the averaged moments of (M)."""
    return z_score(s - s0, math.sqrt(window) * absolute_error(moments, q, s0))


def gain_scores(gains: np.ndarray, start: np.ndarray, errors: np.ndarray) -> list[float]:
    """z of the learned calibration against its start (an error of inf, no information: 0)."""
    return [z_score(float(g - g0), float(e)) for g, g0, e in zip(gains, start, errors)]
