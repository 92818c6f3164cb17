"""The range noise sigma_r(r) = a + b r learned from binned squared range residuals
(docs/METHOD.md, "Noise learned online").

:class:`RangeBins` keeps, per range bin, the stochastic averages of (r, r^2, e_r^2);
:func:`range_noise_fit` fits (a, b) to them by iteratively reweighted least squares.
"""
from __future__ import annotations

import numpy as np

from .averages import batch_step_sizes

# Range bins of the sigma_r(r) = a + b r fit, over [0, min(max_range, RANGE_BIN_REACH)]
# (farther observations share the last bin): the bins only weigh, their means are exact.
RANGE_BINS, RANGE_BIN_REACH = 16, 100.0


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
        bins, sizes, sums = group_sums(index[order], np.array([r, r * r, squared[order]]))
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


def group_sums(index: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(groups (K,), sizes (K,), sums (K, Q)) of ``values`` (Q, n, rows contiguous) by the sorted
    group ``index`` (n,).

    Each sum is np.add.reduce of a contiguous run of a row: numpy's pairwise summation of
    the group's values in their order, so sum / size is bit for bit np.mean of the group.
    A scan's few observations are mostly each in a bin of its own: then each sum is
    np.add.reduce's of one value, 0 + the value, made for all at once.
    """
    breaks = index[1:] != index[:-1]
    if breaks.all():
        return index, np.ones(index.size, dtype=np.int64), values.T + 0.0
    starts = [0, *(np.flatnonzero(breaks) + 1).tolist()]
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
    reweighted: its fixed point is the maximum-likelihood one).  Each iteration
    evaluates v_j once: the accepted trial's is the next iteration's.
    """
    if counts.size == 0 or not any(free):
        return a, b
    r, r2, e2 = means.T.copy()                           # contiguous rows: numpy's faster loops
    params = (float(a), float(b))                         # Python floats: the same IEEE arithmetic, no arrays
    variance = _range_variance(r, r2, params)
    for _ in range(iterations):
        weights = counts / np.maximum(variance, 1e-300) ** 2
        rho = variance - e2
        step = _gauss_newton_step(r, r2, rho, weights, params, free)
        if all(abs(d) <= 1e-9 * abs(p) + 1e-15 for d, p in zip(step, params)):
            break                                         # converged (the averages move slowly)
        cost = float(weights @ rho ** 2)                  # only a step to take needs it
        for _ in range(10):                               # backtrack: keep the cost decreasing
            trial = (params[0] + step[0], params[1] + step[1])
            if trial[0] > 0 and trial[1] >= 0:
                variance = _range_variance(r, r2, trial)
                if float(weights @ (variance - e2) ** 2) <= cost * (1 + 1e-12):
                    break
            step = [0.5 * d for d in step]
        else:
            break
        params = trial
    return params


def _range_variance(r: np.ndarray, r2: np.ndarray, params: tuple[float, float]) -> np.ndarray:
    """E_j[(a + b r)^2] = a^2 + 2ab E_j[r] + b^2 E_j[r^2] per bin (K,), from E_j[r], E_j[r^2] (K,)."""
    a, b = params
    return a * a + 2.0 * a * b * r + b * b * r2


def _gauss_newton_step(r: np.ndarray, r2: np.ndarray, rho: np.ndarray, weights: np.ndarray,
                       params: tuple[float, float], free: tuple[bool, bool]) -> list[float]:
    """-(J^T W J)^-1 J^T W rho on the free parameters (2,), rho the residuals (K,);
    J_j = 2 (a + b E[r], a E[r] + b E[r^2]) (K, 2), only its free columns made.

    One free parameter (the usual case: sigma_range alone): J^T W J and J^T W rho are two
    dot products (the BLAS call a (1, K) x (K, 1) product makes) and LAPACK's solve of one
    equation is the division, done in floats.
    """
    a, b = params
    if free[0] != free[1]:
        j = 2.0 * (a + b * r if free[0] else a * r + b * r2)
        gram, gradient = float(j @ (weights * j)), float(j @ (weights * rho))
        ridge = 1e-12 * max(gram, 1e-300)         # all observations in one bin: b is not identified
        try:
            value = gradient / (gram + ridge)
        except ZeroDivisionError:
            return [0.0, 0.0]
        return [-value, 0.0] if free[0] else [0.0, -value]
    J = (2.0 * np.array([a + b * r, a * r + b * r2])).T      # (K, 2): J^T's rows contiguous, as BLAS had them
    G = J.T @ (weights[:, None] * J)
    ridge = 1e-12 * max(G.trace(), 1e-300)
    try:
        solution = np.linalg.solve(G + ridge * np.eye(2), J.T @ (weights * rho))
    except np.linalg.LinAlgError:
        return [0.0, 0.0]
    return [-float(solution[0]), -float(solution[1])]
