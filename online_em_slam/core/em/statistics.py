"""E-step sufficient statistics, their smoothing over particles, and the M-step.

Per observation of landmark k at pose X (docs/METHOD.md, "Model"), with H the
Jacobian of h in theta at the current estimate theta_bar and P = R^-1 (the
mixture weighs R_c^-1 by the responsibilities):

    A = H^T P H,          b = H^T P (y - h(X, theta_bar) + H theta_bar)          (S)

packed as the 5-vector (A00, A01, A11, b0, b1).  The M-step solves
theta_k = A_k^-1 b_k on the smoothed statistics (one Gauss-Newton step).

Each particle i carries tau^i (N, M, 5).  The smoothers of section 2 propagate
it from the particles at t-1 to those at t:

    forward   tau_t^i = sum_j beta_t(i, j) tau_{t-1}^j,  beta_t(i, j) ∝ w_{t-1}^j m(xi_{t-1}^j, xi_t^i)
    paris     tau_t^i = (1/K) sum_k tau_{t-1}^{J_ik},   J_ik ~ beta_t(i, .) by accept-reject
    ancestry  tau_t^i = tau_{t-1}^{a_i}

before the new statistic is blended in (online EM) or added (block EM).  Each is
a small piece with one interface, :class:`Smoother` (``update(tau_prev, data)``),
and ``SMOOTHERS`` picks one by its ``filter.smoother`` name (:func:`make_smoother`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..models.angles import wrap_angle
from ..models.gaussian import gaussian_transition_logpdf

if TYPE_CHECKING:
    from ..config import FilterConfig
    from .step import FilterStepData

STAT_DIM = 5


def observation_statistics(H: np.ndarray, precision: np.ndarray, nu: np.ndarray,
                           theta_bar: np.ndarray) -> np.ndarray:
    """Equation (S) for Jacobians H (..., 2, 2), precisions (..., 2, 2), innovations (..., 2).

    theta_bar broadcasts against the leading axes (e.g. (P, 2) for (N, P, ...)).
    """
    PH = precision @ H
    A = np.swapaxes(H, -1, -2) @ PH
    target = nu + np.einsum("...ij,...j->...i", H, np.broadcast_to(theta_bar, nu.shape))
    b = np.einsum("...ji,...j->...i", PH, target)
    out = np.empty(nu.shape[:-1] + (STAT_DIM,))
    out[..., 0] = A[..., 0, 0]
    out[..., 1] = 0.5 * (A[..., 0, 1] + A[..., 1, 0])
    out[..., 2] = A[..., 1, 1]
    out[..., 3:] = b
    return out


def unpack(stats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A (..., 2, 2), b (..., 2)) from packed statistics (..., 5)."""
    A = np.empty(stats.shape[:-1] + (2, 2))
    A[..., 0, 0] = stats[..., 0]
    A[..., 0, 1] = A[..., 1, 0] = stats[..., 1]
    A[..., 1, 1] = stats[..., 2]
    return A, stats[..., 3:5]


def m_step(stats: np.ndarray, rcond: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """theta = A^-1 b per landmark; ``ok`` is False where A is (near) singular or not positive."""
    a00, a01, a11, b0, b1 = (stats[..., i] for i in range(STAT_DIM))
    det = a00 * a11 - a01 * a01
    scale = np.maximum(a00 + a11, 1e-300)
    ok = (det > rcond * scale * scale) & (a00 > 0) & np.isfinite(det)
    safe = np.where(ok, det, 1.0)
    theta = np.stack([(a11 * b0 - a01 * b1) / safe, (a00 * b1 - a01 * b0) / safe], axis=-1)
    return theta, ok & np.all(np.isfinite(theta), axis=-1)


def information_covariance(stats: np.ndarray, inverse_sample_size: np.ndarray) -> np.ndarray:
    """Landmark covariance q A^-1: A is the averaged information per observation,
    q = sum of squared step-size weights (1/n for plain averaging)."""
    A, _ = unpack(stats)
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] ** 2
    safe = np.where(det > 1e-300, det, np.inf)
    cov = np.empty_like(A)
    cov[..., 0, 0] = A[..., 1, 1] / safe
    cov[..., 1, 1] = A[..., 0, 0] / safe
    cov[..., 0, 1] = cov[..., 1, 0] = -A[..., 0, 1] / safe
    return cov * inverse_sample_size[..., None, None]


def differing_landmarks(tau: np.ndarray, rtol: float = 1e-6) -> np.ndarray:
    """Landmarks whose statistic still differs between particles (M,) bool.

    A statistic equal in every particle (to ``rtol`` of its magnitude) is a
    fixed point of any smoothing kernel whose rows sum to one.
    """
    spread = np.ptp(tau, axis=0).max(axis=-1)
    scale = np.abs(tau[0]).max(axis=-1)
    return spread > rtol * np.maximum(scale, 1e-300)


def backward_kernel(log_weights_prev: np.ndarray, means: np.ndarray, covariances: np.ndarray,
                    particles: np.ndarray) -> np.ndarray:
    """beta_t(i, j) ∝ w_{t-1}^j m(xi_{t-1}^j, xi_t^i), rows normalised: (N_t, N_{t-1}).

    ``means``/``covariances`` are the Gaussian transition (T) from each particle j
    at t-1 to time t.  Rows with no finite entry fall back to the weights.
    """
    logk = gaussian_transition_logpdf(particles, means, covariances) + log_weights_prev[None, :]
    top = logk.max(axis=1, keepdims=True)
    bad = ~np.isfinite(top[:, 0])
    if bad.any():
        logk[bad] = log_weights_prev
        top[bad, 0] = logk[bad].max(axis=1)
    kernel = np.exp(logk - top)
    kernel /= kernel.sum(axis=1, keepdims=True)
    return kernel


def forward_smooth(tau_prev: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """tau_t^i = sum_j beta(i, j) tau_{t-1}^j as one matrix product."""
    n_prev = tau_prev.shape[0]
    return (kernel @ tau_prev.reshape(n_prev, -1)).reshape((kernel.shape[0],) + tau_prev.shape[1:])


def paris_indices(log_weights_prev: np.ndarray, means: np.ndarray, covariances: np.ndarray,
                  particles: np.ndarray, draws: int, rng: np.random.Generator,
                  max_rounds: int = 8) -> np.ndarray:
    """J (N, K): K draws per particle i from beta_t(i, .) (PaRIS, Olsson & Westerborn 2017).

    Accept-reject with proposal j ~ w_{t-1} and acceptance
    m(xi_j, xi_i) / max_j' sup m(xi_j', .), O(N K) on average; draws still
    pending after ``max_rounds`` rounds are taken exactly from their rows.
    """
    n, n_prev = particles.shape[0], means.shape[0]
    weights = np.exp(log_weights_prev - log_weights_prev.max())
    cumulative = np.cumsum(weights / weights.sum())
    cumulative[-1] = 1.0
    inv = np.linalg.inv(covariances)
    _, logdet = np.linalg.slogdet(covariances)
    log_norm = -0.5 * logdet - 1.5 * np.log(2 * np.pi)
    log_bound = log_norm.max()
    result = np.full((n, draws), -1, dtype=np.int64)
    pending_i, pending_k = np.divmod(np.arange(n * draws), draws)
    for _ in range(max_rounds):
        if pending_i.size == 0:
            break
        j = np.minimum(np.searchsorted(cumulative, rng.random(pending_i.size), side="right"), n_prev - 1)
        diff = particles[pending_i] - means[j]
        diff[:, 2] = wrap_angle(diff[:, 2])
        logm = log_norm[j] - 0.5 * np.einsum("pi,pij,pj->p", diff, inv[j], diff)
        accept = np.log(rng.random(pending_i.size)) < logm - log_bound
        result[pending_i[accept], pending_k[accept]] = j[accept]
        pending_i, pending_k = pending_i[~accept], pending_k[~accept]
    if pending_i.size:
        rows, row_index = np.unique(pending_i, return_inverse=True)
        kernel = backward_kernel(log_weights_prev, means, covariances, particles[rows])
        cumulative_rows = np.cumsum(kernel, axis=1)
        u = rng.random(pending_i.size)[:, None]
        drawn = (cumulative_rows[row_index] < u).sum(axis=1)
        result[pending_i, pending_k] = np.minimum(drawn, n_prev - 1)
    return result


def paris_smooth(tau_prev: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """tau_t^i = (1/K) sum_k tau_{t-1}^{J_ik}."""
    return tau_prev[indices].mean(axis=1)


# ------------------------------------------------------------ smoothers
class Smoother(Protocol):
    """Carries per-particle statistics (N_{t-1}, ...) to the particles at t (N_t, ...).

    ``whole_table``: apply it to every landmark's statistic.  Otherwise only to
    those that still differ across particles: a kernel whose rows sum to one
    leaves a statistic equal in every particle as it is.
    """

    whole_table: bool

    def update(self, tau_prev: np.ndarray, data: FilterStepData) -> np.ndarray:
        """tau_t from tau_{t-1} and the filter step's particles, weights and transition (T)."""


class ForwardSmoother:
    """Forward-only smoothing: tau_t^i = sum_j beta_t(i, j) tau_{t-1}^j, one (N x N) kernel, O(N^2)."""

    whole_table = False

    def __init__(self, config: FilterConfig, rng: np.random.Generator) -> None:
        pass

    def update(self, tau_prev: np.ndarray, data: FilterStepData) -> np.ndarray:
        kernel = backward_kernel(data.log_weights_prev, data.transition_means, data.transition_covs,
                                 data.particles)
        return forward_smooth(tau_prev, kernel)


class ParisSmoother:
    """PaRIS: tau_t^i = (1/K) sum_k tau_{t-1}^{J_ik}, K = ``paris_draws`` draws from beta_t(i, .), O(NK)."""

    whole_table = False

    def __init__(self, config: FilterConfig, rng: np.random.Generator) -> None:
        self.draws = config.paris_draws
        self.rng = rng

    def update(self, tau_prev: np.ndarray, data: FilterStepData) -> np.ndarray:
        indices = paris_indices(data.log_weights_prev, data.transition_means, data.transition_covs,
                                data.particles, self.draws, self.rng)
        return paris_smooth(tau_prev, indices)


class AncestrySmoother:
    """Ancestry: tau_t^i = tau_{t-1}^{a_i}, O(N); degenerates on long horizons.

    A copy costs no more than selecting the statistics that still differ, so it
    is applied to every landmark.
    """

    whole_table = True

    def __init__(self, config: FilterConfig, rng: np.random.Generator) -> None:
        pass

    def update(self, tau_prev: np.ndarray, data: FilterStepData) -> np.ndarray:
        return tau_prev[data.ancestors]


SMOOTHERS: dict[str, type] = {"forward": ForwardSmoother, "paris": ParisSmoother, "ancestry": AncestrySmoother}


def make_smoother(config: FilterConfig, rng: np.random.Generator) -> Smoother:
    """The smoother named by ``config.smoother`` (one of core.config.SMOOTHERS)."""
    return SMOOTHERS[config.smoother](config, rng)
