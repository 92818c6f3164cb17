"""The motion scale's statistic (M) of docs/METHOD.md, "Noise learned online".

The pose predicted open loop over the last L filter steps from the posterior
at t - L gives the scan's prediction error nu = nubar_t - H_x C, whose
covariance is K + s G (G = H_x Q_L H_x^T the window's motion noise at scale 1,
K the rest), so s = sum_t (nu^T W nu - tr(W K)) / sum_t tr(W G).  The window
of filter steps, its compounding and the statistic live here; the learner
(learner.py) averages it; motion_gains.py uses the same window for the
calibration of the motion input.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

# A filter step informs the motion scale when at least this many of the transition's
# three dimensions are motion noise rather than jitter.
MIN_MOTION_DIMENSIONS = 0.5


def ratio_error(moments: np.ndarray, squared_weights: float) -> float:
    """Relative standard error of s = E[b] / E[a] from the averages (E[a], E[b], E[a^2], E[ab], E[b^2])
    of independent samples (a, b) with weights whose squares sum to ``squared_weights``.

    Delta method: s - s* ~ sum_i w_i (b_i - s a_i) / E[a], so Var(s) = q E[(b - s a)^2] / E[a]^2.
    A non-positive s has no relative error: inf.
    """
    a, b, aa, ab, bb = moments
    s = b / a
    if not s > 0.0:
        return math.inf
    residual = max(bb - 2.0 * s * ab + s * s * aa, 0.0)
    return float(math.sqrt(squared_weights * residual) / (a * s))


def absolute_error(moments: np.ndarray, squared_weights: float, s: float) -> float:
    """Standard error of s = E[b] / E[a] around the value ``s`` (delta method, as :func:`ratio_error`):
    sqrt(q E[(b - s a)^2]) / E[a]; inf unless E[a] > 0."""
    a, _, aa, ab, bb = moments
    if not a > 0.0:
        return math.inf
    return float(math.sqrt(squared_weights * max(bb - 2.0 * s * ab + s * s * aa, 0.0)) / a)


@dataclass
class MotionSteps:
    """Filter steps of the motion-scale window, oldest first (L of them): residuals
    c_t = f(xbar_{t-1}) - xbar_t (L, 3), Jacobians F_t, motion noise covariances Q_t at
    scale 1, jitters J_t and posterior spreads P_t (L, 3, 3 each)."""

    c: np.ndarray
    F: np.ndarray
    Q: np.ndarray
    J: np.ndarray
    P: np.ndarray

    def __getitem__(self, index: slice) -> MotionSteps:
        return MotionSteps(self.c[index], self.F[index], self.Q[index], self.J[index], self.P[index])


class MotionWindow:
    """The last ``size`` filter steps' :class:`MotionSteps`, kept in place in stacked arrays
    (a push shifts them by one): no per-step objects, no copies to read the window."""

    def __init__(self, size: int) -> None:
        self.size, self.count = size, 0
        self.steps = MotionSteps(np.zeros((size, 3)), *(np.zeros((size, 3, 3)) for _ in range(4)))

    @property
    def full(self) -> bool:
        return self.count >= self.size

    def append(self, c: np.ndarray, F: np.ndarray, Q: np.ndarray, J: np.ndarray, P: np.ndarray) -> None:
        for stack, value in zip((self.steps.c, self.steps.F, self.steps.Q, self.steps.J, self.steps.P),
                                (c, F, Q, J, P)):
            stack[:-1] = stack[1:]
            stack[-1] = value
        self.count += 1


def compound(steps: MotionSteps, Phi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """C = sum_k Phi(t, k) c_k, Q_L = sum_k Phi Q_k Phi^T, J_L (the jitter's), Phi(t, start) over ``steps``.

    C is what the window's motion residuals add up to at its end: the open-loop
    prediction of the pose at t from the posterior at the window's start, minus
    the posterior mean at t; Q_L is its motion covariance at scale 1.  ``Phi``:
    :func:`transitions` of the steps' Jacobians, when already made.

    The terms are one stacked matmul each (per matrix the same BLAS call) and summed
    newest first from zero.
    """
    L = steps.c.shape[0]
    Phi = transitions(steps.F) if Phi is None else Phi
    Phis, PhisT = Phi[1:], Phi[1:].transpose(0, 2, 1)
    terms = np.concatenate([(Phis @ steps.c[..., None]).reshape(L, 3), (Phis @ steps.Q @ PhisT).reshape(L, 9),
                            (Phis @ steps.J @ PhisT).reshape(L, 9)], axis=1)
    total = _running_total(terms[::-1])
    return total[:3], total[3:12].reshape(3, 3), total[12:].reshape(3, 3), Phi[0]


def transitions(F: np.ndarray) -> np.ndarray:
    """Phi (L + 1, 3, 3) of Jacobians F (L, 3, 3): Phi[k + 1] = Phi(t, k) = F_{L-1} ... F_{k+1} of
    step k, Phi[0] the whole window's; built from the end backwards, one 3x3 product per step
    (the same products in the same order as one step at a time).  np.dot into ``out``: the
    same BLAS call as matmul for two matrices, with less of numpy's overhead per call, which
    is what L products of 3x3 matrices cost."""
    L = F.shape[0]
    Phi = np.empty((L + 1, 3, 3))
    Phi[L] = np.eye(3)
    products, factors = list(Phi), list(F)                # each matrix's view, made once
    for k in range(L - 1, -1, -1):
        np.dot(products[k + 1], factors[k], out=products[k])
    return Phi


def compounded_noise(Phi: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """sum_k Phi(t, k) Q_k Phi(t, k)^T (3, 3) of :func:`transitions` Phi (L + 1, 3, 3) and
    covariances Q (L, 3, 3): :func:`compound`'s Q_L (each entry's running total on its own)."""
    Phis = Phi[1:]
    return _running_total((Phis @ Q @ Phis.transpose(0, 2, 1)).reshape(-1, 9)[::-1]).reshape(3, 3)


def _running_total(terms: np.ndarray) -> np.ndarray:
    """((0 + terms[0]) + terms[1]) + ... over the first axis of ``terms`` (L, ...).

    A cumulative sum adds strictly in order; starting from terms[0] instead of 0 + terms[0]
    can differ only in the sign of a zero while every partial sum is zero, which the final
    + 0.0 settles as the start from +0 did (x + 0.0 is x otherwise).
    """
    if terms.shape[0] == 0:
        return np.zeros(terms.shape[1:])
    return np.cumsum(terms, axis=0)[-1] + 0.0


def prediction_statistic(steps: MotionSteps, pose_jacobian: np.ndarray, innovation: np.ndarray,
                         noise_cov: np.ndarray, weight_scale: float = 1.0) -> np.ndarray | None:
    """(tr(W G), nu^T W nu - tr(W K)) of the scan at the window's end: s = mean 2nd / mean 1st, (M).

    nu = nubar - H_x C (2P) is the scan's innovation against the pose predicted
    open loop over the window from the posterior at its start (steps[0] only
    gives that posterior's spread P_0), ``innovation`` nubar the posterior mean
    innovation at t and ``pose_jacobian`` H_x = dh/dX.  Its covariance is
    S(s) = K + s G with G = H_x Q_L H_x^T, K = H_x (Phi P_0 Phi^T + J_L) H_x^T
    + ``noise_cov`` (R and the map term), so E[nu^T W nu - tr(W K)] = s tr(W G)
    for any W fixed before the scan.  W = S(s')^-1 G S(s')^-1, the score's weight
    at ``weight_scale`` s' (the scale in use: near the truth once learned, where the
    weight is the efficient one; started at 1/9 of the truth, the configured scale's
    weight left the estimate more than 15 % off in 28 of 80 runs, this one in 20).  A
    prediction error, unlike the posterior's residuals, is not pulled towards
    the motion noise the filter assumed: EM's statistic would approach the
    true scale by a fraction per pass only (one step's motion noise is small
    next to the pose's uncertainty, so most of its information is missing).
    """
    C, Q, J, Phi = compound(steps[1:])
    Hx = pose_jacobian.reshape(-1, 3)                                    # (2P, 3)
    nu = innovation.reshape(-1) - Hx @ C
    G = Hx @ Q @ Hx.T
    K = Hx @ (Phi @ steps.P[0] @ Phi.T + J) @ Hx.T + block_diagonal(noise_cov)
    try:
        if np.linalg.solve(Q + J, Q).trace() < MIN_MOTION_DIMENSIONS:
            return None                   # standing still: the jitter is all the window moved
        S_inv = np.linalg.inv(K + weight_scale * G)
    except np.linalg.LinAlgError:
        return None
    W = S_inv @ G @ S_inv
    sample = np.array([(W @ G).trace(), nu @ W @ nu - (W @ K).trace()])
    return sample if np.isfinite(sample).all() and sample[0] > 0 else None


def shape_statistic(steps: MotionSteps, parts: np.ndarray, pose_jacobian: np.ndarray, innovation: np.ndarray,
                    noise_cov: np.ndarray, scales: np.ndarray) -> np.ndarray | None:
    """(A (m, m) flattened, b (m,)) of the window's scan for the scales s of m noise groups:
    E[nu^T W_j nu - tr(W_j K)] = sum_k s_k tr(W_j G_k), G_k = H_x Q_L^k H_x^T the window's motion
    noise of group k at unit scale (``parts`` (L + 1, m, 3, 3), per step), W_j = S^-1 G_j S^-1 at
    the ``scales`` in use (the score's weights), K as in :func:`prediction_statistic`.  A group
    the window did not excite (a robot that did not turn) has a zero row and column."""
    m = parts.shape[1]
    transition = transitions(steps.F[1:])
    C, _, J, Phi = compound(steps[1:], transition)
    Hx = pose_jacobian.reshape(-1, 3)
    nu = innovation.reshape(-1) - Hx @ C
    G = [Hx @ compounded_noise(transition, parts[1:, k]) @ Hx.T for k in range(m)]
    K = Hx @ (Phi @ steps.P[0] @ Phi.T + J) @ Hx.T + block_diagonal(noise_cov)
    try:
        S_inv = np.linalg.inv(K + sum(scale * g for scale, g in zip(scales, G)))
    except np.linalg.LinAlgError:
        return None
    W = [S_inv @ g @ S_inv for g in G]
    A = np.array([[np.trace(W[j] @ G[k]) for k in range(m)] for j in range(m)])
    b = np.array([nu @ W[j] @ nu - np.trace(W[j] @ K) for j in range(m)])
    z = np.concatenate([A.ravel(), b])
    return z if np.isfinite(z).all() and A.trace() > 0 else None


def group_scales(A: np.ndarray, b: np.ndarray, low: float, high: float, current: np.ndarray) -> np.ndarray:
    """The scales s of the averaged system A s = b, each within [low, high].

    A s = b is the gradient of q(s) = s^T A s / 2 - b^T s (A symmetric positive semi-definite),
    so the bounded estimate minimises q over the box.  Each group is at the floor, at the
    ceiling or free (its scale from the free groups' sub-system, :func:`_split_solution`);
    the split is found by an active-set search (:func:`_active_set`), whose answer meets the
    box's optimality conditions, which for a convex q make it the minimum.  Groups the data
    have not excited (zero diagonal) keep ``current``; nearly collinear groups (a constant
    speed makes the constant and the relative speed noise alike) then share what the data
    give them without running off to opposite limits.  Should the search not settle, every
    split is tried (:func:`_enumerated_split`, 3^m small solves) and the feasible one with the
    least q wins.
    """
    scales = np.array(current, dtype=float)
    informed = np.flatnonzero(np.diag(A) > 0)
    if informed.size == 0:
        return scales
    A_i, b_i = A[np.ix_(informed, informed)], b[informed]
    status = _active_set(A_i, b_i, low, high)
    best = _split_solution(A_i, b_i, status, low, high) if status is not None else _enumerated_split(A_i, b_i, low,
                                                                                                     high)
    if best is not None:
        scales[informed] = best
    return scales


def _split_solution(A: np.ndarray, b: np.ndarray, status: np.ndarray, low: float, high: float) -> np.ndarray:
    """s of one split (``status`` per group: 0 at the floor, 1 free, 2 at the ceiling): the free
    groups solve their rows of A s = b with the others at their limits.  Raises LinAlgError
    on a singular sub-system."""
    s = np.where(status == 2, high, low).astype(float)
    free = status == 1
    if free.any():
        fixed = ~free
        s[free] = np.linalg.solve(A[np.ix_(free, free)], b[free] - A[np.ix_(free, fixed)] @ s[fixed])
    return s


def _active_set(A: np.ndarray, b: np.ndarray, low: float, high: float) -> np.ndarray | None:
    """The split at q's minimum over the box, by a primal active-set search from all free: a
    free group's scale beyond a limit (the farthest first) is held there; a held group whose
    gradient g = A s - b pulls it inside (a multiplier of the wrong sign, the largest first) is
    freed again.  It stops where neither happens, the box's optimality conditions; None when
    a sub-system is singular or it has not stopped after 3^m changes."""
    m = b.size
    status = np.ones(m, dtype=int)
    scale = max(float(np.abs(A).max()) * max(abs(low), abs(high)), float(np.abs(b).max()), 1e-300)
    for _ in range(3 ** m):
        try:
            s = _split_solution(A, b, status, low, high)
        except np.linalg.LinAlgError:
            return None
        outside = np.where(status == 1, np.maximum(low - s, s - high), 0.0)
        if outside.max() > 0.0:
            i = int(np.argmax(outside))
            status[i] = 0 if s[i] < low else 2
            continue
        g = A @ s - b
        wrong = np.where(status == 0, -g, np.where(status == 2, g, 0.0))
        if wrong.max() <= 1e-12 * scale:
            return status
        status[int(np.argmax(wrong))] = 1
    return None


def _enumerated_split(A: np.ndarray, b: np.ndarray, low: float, high: float) -> np.ndarray | None:
    """The feasible split with the least q of all 3^m (each group at the floor, free or at the
    ceiling); None if none is feasible."""
    best, best_q = None, np.inf
    for status in itertools.product((0, 1, 2), repeat=b.size):
        try:
            s = _split_solution(A, b, np.array(status), low, high)
        except np.linalg.LinAlgError:
            continue
        free = np.array(status) == 1
        if np.any(s[free] < low) or np.any(s[free] > high):
            continue
        q = 0.5 * s @ A @ s - b @ s
        if q < best_q:
            best, best_q = s, q
    return best


def block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """(P, 2, 2) -> (2P, 2P)."""
    p = blocks.shape[0]
    out = np.zeros((p, 2, p, 2))
    out[np.arange(p), :, np.arange(p), :] = blocks
    return out.reshape(2 * p, 2 * p)
