"""Where the outliers' cost to the map sits: the simulation's 5 % outliers at 25 R, with each
landmark's first k observations replaced by the same draw without the outlier.

    python docs/scripts/outlier_first_observations.py [1-30]

The simulator draws the same noise with and without outliers (the outlier flags scale
the same W), so "clean", "dirty" and the hybrids differ only in where the outliers are.
All runs are given the true noise (the Gaussian; the true 0.95/0.05 mixture with
outliers), no learning.  Prints the map RMSE and shape error, paired with the clean
run, per variant (docs/RESULTS.md, "Noise learned online", third pass).  About
3 minutes for 30 seeds on two cores.
"""
import online_em_slam  # noqa: F401  (first: one BLAS thread per worker process)

import copy
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "test"))
from test_noise_learning import PARTICLES, TRUTH, run  # noqa: E402
from online_em_slam.offline.evaluation import landmark_pairs_by_id, map_error_split  # noqa: E402
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for  # noqa: E402


def errs(slam, sc):
    l = slam.landmarks()
    return [float(x) for x in map_error_split(*landmark_pairs_by_id(l.ids, l.positions, sc.landmarks))]


def hybrid(clean, dirty, k):
    """dirty's observations, but each landmark's first k observations from clean."""
    sc = copy.deepcopy(dirty); seen = {}
    for st, cs in zip(sc.steps, clean.steps):
        assert np.array_equal(st.ids, cs.ids)
        for j, i in enumerate(st.ids):
            c = seen.get(int(i), 0)
            if c < k:
                st.ranges[j] = cs.ranges[j]; st.bearings[j] = cs.bearings[j]
            seen[int(i)] = c + 1
    return sc


def one(seed):
    clean = simulate(ScenarioConfig(seed=seed, outlier_probability=0.0, **TRUTH))
    dirty = simulate(ScenarioConfig(seed=seed, outlier_probability=0.05, **TRUTH))
    cfg_c = slam_config_for(clean, num_particles=PARTICLES); cfg_d = slam_config_for(dirty, num_particles=PARTICLES)
    out = {"clean": errs(run(clean, cfg_c), clean), "dirty": errs(run(dirty, cfg_d), dirty)}
    for k in (1, 10, 50):
        h = hybrid(clean, dirty, k); out[f"first{k}"] = errs(run(h, cfg_d), h)
    return out


if __name__ == "__main__":
    a, b = map(int, (sys.argv[1] if len(sys.argv) > 1 else "1-30").split("-"))
    with Pool(2) as pool:
        res = pool.map(one, range(a, b + 1))
    c = np.array([r["clean"] for r in res])
    for k in res[0]:
        o = np.array([r[k] for r in res]); d = o - c; n = len(c)
        print(f"{k:8s} rmse {o[:,0].mean():.3f} shape {o[:,1].mean():.4f} paired rmse {d[:,0].mean():+.3f}±{d[:,0].std(ddof=1)/np.sqrt(n):.3f} ratio {o[:,0].mean()/c[:,0].mean():.3f} shape ratio {o[:,1].mean()/c[:,1].mean():.3f} ±{d[:,1].std(ddof=1)/np.sqrt(n)/c[:,1].mean():.3f}")
