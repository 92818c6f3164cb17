"""Marginal-SLAM (Martinez-Cantin 2008): the map by recursive maximum likelihood.

Same model as online EM (docs/METHOD.md, "Model"): the pose X_t is the hidden
state, tracked by the project's particle filter (same motion model, proposal,
association and weights), and the map theta is a parameter.  Instead of an EM
M-step, theta climbs the log-likelihood by stochastic gradient:

    theta_t = theta_{t-1} + gamma_n Sigma_k grad_k log p_theta(y_t | y_{1:t-1})          (RML)

Score.  The transition does not depend on theta, so by Fisher's identity

    grad log p_theta(y_{1:t}) = E[ sum_s grad log g(y_s | X_s, theta) | y_{1:t} ],

an additive functional of the path, smoothed exactly like the E-step's
statistics (forward-only smoothing, Del Moral, Doucet & Singh 2010; PaRIS or
ancestry by ``filter.smoother``): each particle carries the accumulated score
alpha_t^i = sum_j beta_t(i, j) alpha_{t-1}^j + s_t(xi_t^i) and
G_t = sum_i w_t^i alpha_t^i.  The gradient of the predictive log-likelihood
is the increment G_t - G_{t-1} (Poyiadjis, Doucet & Singh 2011).  The
observation's own score is s = H^T P nu (P the responsibility-weighted R^-1);
in the seed's statistics (S) it is b - A theta_bar, the gradient of the
quadratic surrogate at theta_bar, so it is computed from them.  The increment
also moves landmarks not seen at t: the new observation re-weights the past
poses, hence the expected past scores (the missing-information coupling).
As in online EM, scores of the past are kept at the map they were computed
with (the propagation approximation): memory does not grow with t.

Step size and preconditioner.  gamma_n = n^-a per landmark, n its number of
observations, a = ``em.step_size_exponent`` (the online-EM step size, so both
methods decay alike).  Sigma_k = Ibar_k^-1, Ibar_k the complete-data
information per observation (sum_i w^i H^T P H), averaged with the same
gamma_n.  Why: the score's scale is that information, so without it one
gamma_n cannot fit near and far landmarks (range and bearing enter H with
1/r and 1/r^2); with it the first step (n = 1, gamma = 1) is the
Gauss-Newton step of the observation, and with known poses the recursion is
exactly the online-EM recursion (theta_n = theta_{n-1} + gamma_n Ibar_n^-1
H^T P (y - H theta_{n-1}) is A_n theta_n = b_n with both statistics blended by
gamma_n), so what separates the two methods is the gradient step versus the
EM fixed point, not a tuning of scale.  With a = 1 it is recursive least squares.
"""
from __future__ import annotations

import numpy as np

from ..core.config import SlamConfig
from ..core.em.complete import inverse_observation_spread
from ..core.em.step import FilterStepData
from ..core.mapping.landmarks import LandmarkTable
from ..core.models.observation import inv_det_2x2
from ..core.filter.slam import OnlineEMSlam
from ..core.em.statistics import STAT_DIM, differing_landmarks, make_smoother, observation_statistics, unpack


def observation_score_and_information(data: FilterStepData, theta_bar: np.ndarray
                                      ) -> tuple[np.ndarray, np.ndarray]:
    """Per particle score s = H^T P nu (N, P, 2) and information H^T P H (N, P, 2, 2).

    Both come from the E-step statistics (S): A = H^T P H, b - A theta_bar = H^T P nu.
    """
    A, b = unpack(observation_statistics(data.H, data.precision, data.nu, theta_bar[None]))
    score = b - np.einsum("npij,pj->npi", A, theta_bar)
    return score, A


def step_sizes(count: np.ndarray, exponent: float) -> np.ndarray:
    """gamma_n = n^-a (n >= 1)."""
    return np.maximum(count, 1).astype(float) ** (-exponent)


class RecursiveMLMapUpdate:
    """The MStep piece of marginal-SLAM: one preconditioned gradient step of the map per filter step."""

    def __init__(self, config: SlamConfig, n_particles: int, rng: np.random.Generator,
                 step_size_exponent: float | None = None) -> None:
        self.config = config
        self._rng = rng
        self._smoother = make_smoother(config.filter, rng)
        self.exponent = config.em.step_size_exponent if step_size_exponent is None else float(step_size_exponent)
        self.alpha = np.zeros((n_particles, 0, 2))    # accumulated score given the particle's pose
        self.differing = np.zeros(0, dtype=bool)       # alpha may still differ across particles
        self.information = np.zeros((0, 2, 2))         # Ibar_k: complete-data information per observation
        self.spread = np.zeros((0, 2, 2))              # pose-induced landmark covariance (SA average)
        self.count = np.zeros(0, dtype=np.int64)       # observations n_k (step sizes)
        self.inv_n = np.zeros(0)                       # sum of squared SA weights (covariance)
        self.last_step = np.zeros((0, 2))              # the step of the last update (diagnostics)

    _ROW_FIELDS = ("differing", "information", "spread", "count", "inv_n", "last_step")

    # ------------------------------------------------------------ rows
    def add_landmarks(self, count: int) -> None:
        n = self.alpha.shape[0]
        self.alpha = np.concatenate([self.alpha, np.zeros((n, count, 2))], axis=1)
        self.differing = np.concatenate([self.differing, np.zeros(count, dtype=bool)])
        self.information = np.concatenate([self.information, np.zeros((count, 2, 2))])
        self.spread = np.concatenate([self.spread, np.zeros((count, 2, 2))])
        self.count = np.concatenate([self.count, np.zeros(count, dtype=np.int64)])
        self.inv_n = np.concatenate([self.inv_n, np.ones(count)])
        self.last_step = np.concatenate([self.last_step, np.zeros((count, 2))])

    def keep_landmarks(self, keep: np.ndarray) -> None:
        for name in self._ROW_FIELDS:
            setattr(self, name, getattr(self, name)[keep])
        self.alpha = self.alpha[:, keep]

    # ------------------------------------------------------------ gradient step
    def update(self, data: FilterStepData, table: LandmarkTable) -> None:
        """Smooth the scores, add the step's, and step theta along the score increment."""
        touched = self._touched_landmarks(data.rows)
        if not touched.size:
            return None
        previous = self._smoothed_score(data.log_weights_prev, touched)       # G_{t-1}
        self._propagate(data, touched)
        if data.rows.size:
            self._add_observations(data, table)
        increment = data.weights @ self.alpha[:, touched].reshape(data.weights.size, -1)
        increment = increment.reshape(-1, 2) - previous                         # G_t - G_{t-1}
        self._gradient_step(touched, increment, table)
        return None

    def _touched_landmarks(self, rows: np.ndarray) -> np.ndarray:
        """Landmarks whose smoothed score can change: seen now, or alpha still differing.

        Kernel rows and weights sum to one, so a score equal in every particle
        has a zero increment; in a large map most landmarks are collapsed.
        """
        candidates = np.flatnonzero(self.differing)
        if candidates.size:
            self.differing[candidates] = differing_landmarks(self.alpha[:, candidates])
        return np.union1d(np.flatnonzero(self.differing), rows).astype(int)

    def _smoothed_score(self, log_weights: np.ndarray, rows: np.ndarray) -> np.ndarray:
        weights = np.exp(log_weights - log_weights.max())
        return np.einsum("n,nki->ki", weights / weights.sum(), self.alpha[:, rows])

    def _propagate(self, data: FilterStepData, touched: np.ndarray) -> None:
        active = touched[self.differing[touched]]
        if active.size:
            # The E-step's smoother pieces (statistics.py) carry the scores as they carry tau.
            self.alpha[:, active] = self._smoother.update(self.alpha[:, active], data)

    def _add_observations(self, data: FilterStepData, table: LandmarkTable) -> None:
        """alpha += s for the landmarks seen; their counts, information and spread blended by gamma_n."""
        rows = data.rows
        score, information = observation_score_and_information(data, table.theta[rows])
        np.add.at(self.alpha, (slice(None), rows), score)
        self.differing[rows] = True
        self.count[rows] += 1
        gamma = step_sizes(self.count[rows], self.exponent)[:, None, None]
        observed = np.einsum("n,npij->pij", data.weights, information)
        self.information[rows] = (1.0 - gamma) * self.information[rows] + gamma * observed
        spread = inverse_observation_spread(data.sensor, data.y, data.prior_weights)
        self.spread[rows] = (1.0 - gamma) * self.spread[rows] + gamma * spread
        self.inv_n[rows] = (1.0 - gamma[:, 0, 0]) ** 2 * self.inv_n[rows] + gamma[:, 0, 0] ** 2

    def _gradient_step(self, rows: np.ndarray, increment: np.ndarray, table: LandmarkTable) -> None:
        """theta_k += gamma_n Ibar_k^-1 (G_t - G_{t-1})_k for landmarks past the warm-up."""
        preconditioner, det = inv_det_2x2(self.information[rows])
        ready = (self.count[rows] >= self.config.em.min_updates_before_mstep) & (det > 1e-300)
        gamma = step_sizes(self.count[rows], self.exponent)
        step = gamma[:, None] * np.einsum("kij,kj->ki", preconditioner, increment)
        ready &= np.all(np.isfinite(step), axis=1)
        table.theta[rows[ready]] += step[ready]
        self.last_step[rows] = np.where(ready[:, None], step, 0.0)

    # ------------------------------------------------------------ uncertainty
    def covariances(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """q_k Ibar_k^-1 + spread_k, as the complete-data EM reports: with known poses
        the estimate is the same gamma-weighted combination of observations."""
        inverse, det = inv_det_2x2(self.information[rows])
        inverse = np.where((det > 1e-300)[:, None, None], inverse, 0.0)
        return self.inv_n[rows][:, None, None] * inverse + self.spread[rows]

    def map_covariances(self) -> np.ndarray:
        return self.covariances()

    # ------------------------------------------------------------ persistence
    def saved_arrays(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Ibar packed as complete-data statistics (A, A theta)."""
        m = self.count.shape[0]
        stats = np.zeros((m, STAT_DIM))
        stats[:, 0], stats[:, 1], stats[:, 2] = (self.information[:, 0, 0], self.information[:, 0, 1],
                                                 self.information[:, 1, 1])
        stats[:, 3:] = np.einsum("mij,mj->mi", self.information, theta)
        return {"count": self.count, "inv_n": self.inv_n, "stats": stats, "spread": self.spread,
                "avg_stats": np.zeros((m, STAT_DIM)), "avg_count": np.zeros(m, dtype=np.int64)}

    def restore(self, arrays: dict[str, np.ndarray], theta: np.ndarray) -> None:
        """Counts, information and spread continue; the scores of the past restart at
        zero (collapsed): a loaded map is the starting point, not data to re-weight."""
        self.add_landmarks(theta.shape[0])
        self.information[:], _ = unpack(np.asarray(arrays["stats"], dtype=float))
        self.count[:] = arrays["count"]
        self.inv_n[:] = arrays["inv_n"]
        self.spread[:] = arrays["spread"]


def recursive_ml_factory(step_size_exponent: float | None = None):
    """``m_step_factory`` for :class:`OnlineEMSlam` that plugs in :class:`RecursiveMLMapUpdate`."""
    def factory(config: SlamConfig, initial_pose: np.ndarray, rng: np.random.Generator) -> RecursiveMLMapUpdate:
        return RecursiveMLMapUpdate(config, config.filter.num_particles, rng, step_size_exponent)
    return factory


class MarginalSlam(OnlineEMSlam):
    """Marginal-SLAM: the online-EM particle filter with the map by recursive ML.

    Same public API as :class:`OnlineEMSlam` (``add_control``, ``add_odometry``,
    ``add_observations``, ``pose``, ``landmarks``, map files).
    """

    def __init__(self, config: SlamConfig | None = None, initial_pose=(0.0, 0.0, 0.0),
                 stamp: float | None = None, step_size_exponent: float | None = None) -> None:
        super().__init__(config, initial_pose, stamp, m_step_factory=recursive_ml_factory(step_size_exponent))
