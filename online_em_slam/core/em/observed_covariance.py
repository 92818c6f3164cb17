"""The map's Gaussian in covariance form: its mean and covariance, updated in O(M^2) per segment.

docs/METHOD.md, "Observed-information M-step"; the factors and variables are in
segment_factors.py.  The same Gaussian over z = [dx_key_1 .. dx_key_R; theta] as
observed_information.py holds by its information, held here by its mean mu and covariance
Sigma.  The information form pays one Cholesky factorisation of the whole system per solve,
O(M^3) (60 ms of a 140 ms segment end at M = 1000); here a segment's fold is

1.-2. the segment's variables split into those already stored, T = [key, theta_S seen
   before], the new ones, N = [x_K, theta_S first seen in this segment], and the inner
   poses x_1 .. x_{K-1} (in no other factor); E = [N, inner] integrated out of the segment's
   own small factor (L, l): L_T = L_TT - L_TE L_EE^-1 L_ET, l_T = l_T - L_TE L_EE^-1 l_E;
3. the stored Gaussian updated by the factor on T (Woodbury, a rank-|T| update):
   G = (I + L_T Sigma_TT)^-1,  mu += Sigma_:T G (l_T - L_T mu_T),  Sigma -= Sigma_:T G L_T Sigma_T:;
4. N appended from the factor's conditional N | T = c - C z_T + e, e ~ N(0, P_NN), with
   (C, c, P) = L_EE^-1 (L_ET, l_E, I) restricted to N's rows (the inner poses integrated
   out): mu_N = c - C mu_T, Sigma_N: = -C Sigma_T:, Sigma_NN = P_NN + C Sigma_TT C';
5. the old key dropped (marginalising is deleting in covariance form): x_K takes its slots.

Every step is exact Gaussian algebra, so the mean is the information form's minimiser
(test_observed_covariance.py checks both against each other and against a batch
Gauss-Newton step).  The solve is the mean, free; a pruned landmark is deleted, free; the
marginal covariances are Sigma's diagonal blocks, free.  The cost is O(M^2 |T|) per segment.

Storage: slots in a buffer that grows by half its size; the key blocks first, then a pair of
slots per landmark in the order the landmarks entered; freed pairs are reused.  A landmark
added but not yet folded has no slot (its factors have not arrived: zero information).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ..config import SensorConfig
from ..models.observation import inv_det_2x2
from .segment_factors import MIN_PRIOR_STD, POSE_DIM, SegmentFactors, SegmentSystem, given_key

UNSTORED = -1
# The rank-|T| update runs over blocks of rows: at M = 5000 a whole temporary would be 800 MB.
ROW_BLOCK = 512


class ObservedCovariance(SegmentFactors):
    """Covariance form over [dx_key_1 .. dx_key_R; theta] plus each robot's open segment."""

    def __init__(self, sensor: SensorConfig, initial_pose, initial_pose_std,
                 first_estimates: bool = True, relinearize_threshold: float = np.inf, iterations: int = 1) -> None:
        super().__init__(sensor, initial_pose, first_estimates, relinearize_threshold, iterations)
        std = np.maximum(np.asarray(initial_pose_std, dtype=float), MIN_PRIOR_STD)
        capacity = self.key_dim + 64
        self.mean = np.zeros(capacity)                       # mu over the slots
        self.cov = np.zeros((capacity, capacity))            # Sigma over the slots
        for r in range(self.key_poses.shape[0]):
            self.cov[self._key(r), self._key(r)] = np.diag(std ** 2)
        self.slot = np.zeros(0, dtype=np.int64)              # (M,) each landmark's first slot, or UNSTORED
        self._free: list[int] = []                           # freed landmark slot pairs
        self._top = self.key_dim                             # slots [0, top) in use or freed

    @property
    def n_landmarks(self) -> int:
        return self.slot.size

    # ------------------------------------------------------------ map rows
    def add_landmarks(self, count: int) -> None:
        """New landmarks get slots when their first factors are folded in."""
        if count <= 0:
            return
        self.slot = np.concatenate([self.slot, np.full(count, UNSTORED, dtype=np.int64)])
        self._add_landmark_rows(count)

    def keep_landmarks(self, keep: np.ndarray) -> None:
        """Remove landmarks (``keep`` False): marginalising in covariance form is deleting."""
        keep = np.asarray(keep, dtype=bool)
        self._keep_landmark_rows(keep)
        gone = self.slot[~keep]
        gone = gone[gone != UNSTORED]
        if gone.size:
            pairs = (gone[:, None] + np.arange(2)).ravel()
            self.cov[pairs, :self._top] = 0.0
            self.cov[:self._top, pairs] = 0.0
            self.mean[pairs] = 0.0
            self._free.extend(gone.tolist())
        self.slot = self.slot[keep]

    def _allocate(self, count: int) -> np.ndarray:
        """``count`` landmark slot pairs (their first slots), freed ones first."""
        starts = [self._free.pop() for _ in range(min(count, len(self._free)))]
        fresh = count - len(starts)
        if fresh:
            needed = self._top + 2 * fresh
            if needed > self.mean.size:
                self._reserve(max(needed, self.mean.size + self.mean.size // 2))
            starts.extend(range(self._top, needed, 2))
            self._top = needed
        return np.asarray(starts, dtype=np.int64)

    def _reserve(self, capacity: int) -> None:
        cov = np.zeros((capacity, capacity))
        cov[:self._top, :self._top] = self.cov[:self._top, :self._top]
        self.cov = cov
        self.mean = np.concatenate([self.mean, np.zeros(capacity - self.mean.size)])

    # ------------------------------------------------------------ factors
    def fold(self, segment: SegmentSystem, robot: int = 0) -> None:
        """Add ``segment``'s factor against ``robot``'s key block; its last pose becomes the key
        (steps 1-5 of the module docstring).  Built at another key point (another node's,
        :meth:`move_key` moves them apart), the factor is re-expressed exactly first."""
        shift = segment.key - self.key_poses[robot]
        if np.any(shift):
            self.move_key(shift, robot)
        seen, n_pose = segment.seen, POSE_DIM * (segment.steps + 1)
        stored = self.slot[seen] != UNSTORED
        lm_local = n_pose + 2 * np.arange(seen.size)[:, None] + np.arange(2)
        x_K = np.arange(n_pose - POSE_DIM, n_pose)
        T_local = np.concatenate([np.arange(POSE_DIM), lm_local[stored].ravel()])
        N_local = np.concatenate([x_K, lm_local[~stored].ravel()])
        inner = np.arange(POSE_DIM, n_pose - POSE_DIM)                  # x_1 .. x_{K-1}
        key = np.arange(self._key(robot).start, self._key(robot).stop)
        self.slot[seen[~stored]] = self._allocate(int((~stored).sum()))
        T = np.concatenate([key, (self.slot[seen[stored]][:, None] + np.arange(2)).ravel()])
        N = np.concatenate([key, (self.slot[seen[~stored]][:, None] + np.arange(2)).ravel()])
        L_T, l_T, C, c, P_NN = _split(segment.local, segment.vector, T_local, N_local, inner)
        self._update(T, L_T, l_T)
        self._append(T, N, C, c, P_NN)
        self._key_point_set(segment.pose, robot)

    def segment_solution(self, segment: SegmentSystem, robot: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
        """(dx_1..dx_K (K, 3), theta_S (S, 2)): the mean of the segment's factor times the stored
        Gaussian's marginal of [dx_key; theta_S stored] (Sigma_TT, mu_T), what :meth:`fold` and a
        solve would give them; None if that system is singular or not finite."""
        seen, n_pose = segment.seen, POSE_DIM * (segment.steps + 1)
        stored = self.slot[seen] != UNSTORED
        lm_local = n_pose + 2 * np.arange(seen.size)[:, None] + np.arange(2)
        T_local = np.concatenate([np.arange(POSE_DIM), lm_local[stored].ravel()])
        T = np.concatenate([np.arange(self._key(robot).start, self._key(robot).stop),
                            (self.slot[seen[stored]][:, None] + np.arange(2)).ravel()])
        info, vector = segment.local.copy(), segment.vector.copy()
        try:
            prior = np.linalg.inv(self.cov[np.ix_(T, T)])
            info[np.ix_(T_local, T_local)] += prior
            vector[T_local] += prior @ self.mean[T]
            z = np.linalg.solve(info, vector)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(z)):
            return None
        return z[POSE_DIM:n_pose].reshape(-1, POSE_DIM), z[n_pose:].reshape(-1, 2)

    def _update(self, T: np.ndarray, L_T: np.ndarray, l_T: np.ndarray) -> None:
        """Step 3: the stored Gaussian times the factor exp(-z_T' L_T z_T / 2 + l_T' z_T)."""
        top = self._top
        A = self.cov[:top, T]                                          # Sigma_:T
        S = A[T]
        system = np.eye(T.size) + L_T @ S
        G = np.linalg.solve(system, np.column_stack([L_T, l_T - L_T @ self.mean[T]]))
        W = 0.5 * (G[:, :-1] + G[:, :-1].T)                            # G L_T = (L_T^-1 + Sigma_TT)^-1
        self.mean[:top] += A @ G[:, -1]
        AW = A @ W
        for start in range(0, top, ROW_BLOCK):                         # no top x top temporary
            rows = slice(start, min(start + ROW_BLOCK, top))
            self.cov[rows, :top] -= AW[rows] @ A.T

    def _append(self, T, N, C, c, P_NN) -> None:
        """Steps 4-5: N from the factor's conditional given T, written into its slots (the key's
        slots, whose old key is thereby marginalised, and the new landmarks' slots)."""
        top = self._top
        cross = -C @ self.cov[T, :top]                                 # Sigma_N: (n_N, top)
        block = P_NN - cross[:, T] @ C.T                               # P_NN + C Sigma_TT C'
        mean_N = c - C @ self.mean[T]
        self.cov[N, :top] = cross
        self.cov[:top, N] = cross.T
        self.cov[np.ix_(N, N)] = 0.5 * (block + block.T)
        self.mean[N] = mean_N

    # ------------------------------------------------------------ solve
    def solve(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The mean: (theta (M, 2), NaN for a landmark not yet folded in; dx_keys (3R,): robot r's
        key correction at [3r, 3r + 3)), None if not finite."""
        theta = np.full((self.slot.size, 2), np.nan)
        stored = self.slot != UNSTORED
        theta[stored] = self.mean[self.slot[stored][:, None] + np.arange(2)]
        keys = self.mean[:self.key_dim].copy()
        if not (np.all(np.isfinite(theta[stored])) and np.all(np.isfinite(keys))):
            return None
        return theta, keys

    def move_key(self, shift: np.ndarray, robot: int = 0) -> None:
        """``robot``'s key linearisation point moved by ``shift``: dx_new = dx_old - shift."""
        self.mean[self._key(robot)] -= shift
        self._key_point_moved(shift, robot)

    def restart_key(self, pose: np.ndarray, pose_std, robot: int = 0) -> None:
        """The robot was put at ``pose``: its old key is deleted (integrated out) and the new
        one enters with the prior N(pose, diag(pose_std)^2), untied to the map and other keys."""
        if self.segments[robot]:
            raise RuntimeError("close the segment before restarting the key pose")
        key = self._key(robot)
        std = np.maximum(np.asarray(pose_std, dtype=float), MIN_PRIOR_STD)
        self.cov[key, :self._top] = 0.0
        self.cov[:self._top, key] = 0.0
        self.cov[key, key] = np.diag(std ** 2)
        self.mean[key] = 0.0
        self._key_point_set(pose, robot)

    def add_prior(self, rows: np.ndarray, theta: np.ndarray, A: np.ndarray) -> None:
        """Independent priors N(theta, A^-1) on landmarks ``rows`` not yet stored (a loaded map)."""
        rows = np.asarray(rows)
        starts = self._allocate(rows.size)
        self.slot[rows] = starts
        pairs = starts[:, None] + np.arange(2)
        self.cov[pairs[:, :, None], pairs[:, None, :]] = np.linalg.pinv(A, hermitian=True)
        self.mean[pairs] = theta

    def equality_d2(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """d2 of the hypotheses theta_i = theta_j (pairs of stored landmarks' rows (P,), (P,))
        against the joint Gaussian (P,); inf where S is too ill-conditioned to condition on
        (its condition number beyond about 1e10), so that no merge can break the Gaussian."""
        a, S = self._difference(np.atleast_1d(i), np.atleast_1d(j))
        inv, det = inv_det_2x2(S)
        d2 = np.einsum("pi,pij,pj->p", a, inv, a)
        trace = S[:, 0, 0] + S[:, 1, 1]
        return np.where((det > 1e-10 * trace * trace) & (trace > 0) & np.isfinite(d2), d2, np.inf)

    def condition_equal(self, i: int, j: int) -> None:
        """The Gaussian conditioned on theta_i = theta_j (exact: a linear constraint): mu -= K a,
        Sigma -= K B, B = Sigma_i: - Sigma_j:, K = B^T S^-1.  j is then a copy of i, to be
        deleted as a pruned landmark is (keep_landmarks)."""
        top = self._top
        si, sj = self.slot[i] + np.arange(2), self.slot[j] + np.arange(2)
        a, S = self._difference(np.asarray(i), np.asarray(j))
        B = self.cov[si, :top] - self.cov[sj, :top]                   # (2, top)
        K = np.linalg.solve(S, B).T                                     # (top, 2)
        self.mean[:top] -= K @ a
        self.cov[:top, :top] -= K @ B
        self.cov[:top, :top] = 0.5 * (self.cov[:top, :top] + self.cov[:top, :top].T)

    def _difference(self, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """a = mu_i - mu_j (..., 2) and S = Sigma_ii + Sigma_jj - Sigma_ij - Sigma_ji (..., 2, 2)."""
        si, sj = self.slot[i][..., None] + np.arange(2), self.slot[j][..., None] + np.arange(2)
        c = self.cov
        block = lambda r, q: c[r[..., :, None], q[..., None, :]]          # noqa: E731
        S = block(si, si) + block(sj, sj) - block(si, sj) - block(sj, si)
        return self.mean[si] - self.mean[sj], 0.5 * (S + np.swapaxes(S, -1, -2))

    def landmark_covariances(self) -> np.ndarray:
        """Marginal covariances (M, 2, 2): Sigma's diagonal blocks; NaN where not yet stored."""
        out = np.full((self.slot.size, 2, 2), np.nan)
        stored = self.slot != UNSTORED
        pairs = self.slot[stored][:, None] + np.arange(2)
        out[stored] = self.cov[pairs[:, :, None], pairs[:, None, :]]
        return out

    def covariances_given_key(self, rows: np.ndarray, robot: int = 0) -> np.ndarray:
        """(P, 2, 2) each landmark of ``rows``' covariance given ``robot``'s key pose; NaN where not
        yet stored."""
        out = np.full((len(rows), 2, 2), np.nan)
        slots = self.slot[rows]
        stored = slots != UNSTORED
        if stored.any():
            key = np.arange(self._key(robot).start, self._key(robot).stop)
            pairs = slots[stored][:, None] + np.arange(2)
            c = self.cov
            out[stored] = given_key(c[np.ix_(key, key)], c[pairs[:, :, None], key],
                                    c[pairs[:, :, None], pairs[:, None, :]])
        return out


def _split(L: np.ndarray, l: np.ndarray, T: np.ndarray, N: np.ndarray, inner: np.ndarray):
    """Steps 1-2 at once: the factor (L, l) with E = [N, inner] integrated out, (L_T, l_T), and
    N's conditional given T (the inner poses integrated out of E's):
    N = c - C z_T + e, C = (L_EE^-1 L_ET)_N, c = (L_EE^-1 l_E)_N, e ~ N(0, (L_EE^-1)_NN)."""
    E = np.concatenate([N, inner])
    L_EE, L_ET = L[np.ix_(E, E)], L[np.ix_(E, T)]
    rhs = np.zeros((E.size, T.size + 1 + N.size))
    rhs[:, :T.size], rhs[:, T.size] = L_ET, l[E]
    rhs[np.arange(N.size), T.size + 1 + np.arange(N.size)] = 1.0
    try:
        X = cho_solve(cho_factor(L_EE, lower=True), rhs)
    except LinAlgError:
        X = np.linalg.lstsq(L_EE, rhs, rcond=None)[0]
    L_T = L[np.ix_(T, T)] - L_ET.T @ X[:, :T.size]
    l_T = l[T] - L_ET.T @ X[:, T.size]
    n = N.size
    C, c, P_NN = X[:n, :T.size], X[:n, T.size], X[:n, T.size + 1:]
    return 0.5 * (L_T + L_T.T), l_T, C, c, 0.5 * (P_NN + P_NN.T)
