"""Stochastic-approximation averages of online EM: S_n = S_{n-1} + gamma_n (s - S_{n-1}).

gamma_n = n^-alpha; a batch of P samples with one mean weighs as P single
updates.  The sum of the samples' squared weights is kept, so the variance of
an average is that times the variance of one sample.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def mean(x: np.ndarray, axis: int | None = None):
    """``x.mean(axis)`` bit for bit without its Python wrapper: the same sum (np.add.reduce) over the count."""
    return np.add.reduce(x, axis=axis) / (x.size if axis is None else x.shape[axis])


def batch_step_size(count: float, batch: int, alpha: float) -> float:
    """gamma of ``batch`` consecutive updates n = count+1 .. count+batch with one mean:
    1 - prod_j (1 - n_j^-alpha), so a scan of P observations weighs as P single updates."""
    n = count + np.arange(1, batch + 1, dtype=float)
    return float(1.0 - np.multiply.reduce(1.0 - n ** -alpha))                      # np.prod's reduction


def batch_step_sizes(counts: np.ndarray, batches: np.ndarray, alpha: float) -> np.ndarray:
    """:func:`batch_step_size` of several averages at once (K,): the rows' factors padded with 1
    (a product's exact no-op) and multiplied left to right, as the one-row product is.  One
    update each (a scan's observations in bins of their own): the product is its one factor."""
    if (batches == 1).all():
        return 1.0 - (1.0 - (counts + 1.0) ** -alpha)
    n = counts[:, None] + np.arange(1, batches.max() + 1, dtype=float)                # (K, max batch)
    factors = np.where(n <= (counts + batches)[:, None], 1.0 - n ** -alpha, 1.0)
    return 1.0 - np.multiply.reduce(factors, axis=1)                                 # np.prod's reduction


@dataclass
class StochasticAverage:
    """S_n = S_{n-1} + gamma_n (s - S_{n-1}), gamma_n = n^-alpha (online EM's averaging)."""

    alpha: float
    value: np.ndarray | None = None
    count: int = 0
    squared_weights: float = 0.0        # sum of the samples' squared weights: Var(S) = this x Var(s)

    def blend(self, sample: np.ndarray, batch: int = 1) -> None:
        gamma = 1.0 if self.value is None else batch_step_size(self.count, batch, self.alpha)
        self.value = sample.copy() if self.value is None else self.value + gamma * (sample - self.value)
        self.squared_weights = (1.0 - gamma) ** 2 * self.squared_weights + gamma ** 2 / batch
        self.count += batch
