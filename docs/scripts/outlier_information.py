"""What 5 % outliers cost at best: the Fisher information of a location under the outlier
mixture (1 - p) N(0, R) + p N(0, s R) of the simulation, against N(0, R).

    python docs/scripts/outlier_information.py

Per observation (2-d, whitened), the score of the first coordinate's location is
x1 (f0 + f1 / s) / (f0 + f1), f0, f1 the two components' densities; its mean square,
by Monte Carlo over 2 million draws, is the information relative to the Gaussian's 1.
An efficient estimator's standard deviations grow by 1 / sqrt(information): the floor
under the map error's ratio "with outliers / without" for any estimator that knows
the mixture (docs/RESULTS.md, "Noise learned online").
"""
import numpy as np


def information(p: float, s: float, draws: int = 2_000_000, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    outlier = rng.random(draws) < p
    x = rng.standard_normal((draws, 2)) * np.where(outlier, np.sqrt(s), 1.0)[:, None]
    d2 = (x ** 2).sum(axis=1)
    f0 = (1 - p) * np.exp(-d2 / 2)
    f1 = p * np.exp(-d2 / (2 * s)) / s
    return float(np.mean((x[:, 0] * (f0 + f1 / s) / (f0 + f1)) ** 2))


if __name__ == "__main__":
    for s in (25.0, 100.0, 400.0):
        i = information(0.05, s)
        print(f"5 % outliers at {s:g} R: information {i:.3f} of the Gaussian's, "
              f"standard deviations x {1 / np.sqrt(i):.3f}")
