"""Car Park seeds 0-9: per seed the beacons, errors and learned values of PREFIX_SEED run
directories (``online-em-slam run CP_BAG --params FILE --output PREFIX_SEED --seed SEED
--no-plot``), their means, and with a second prefix the paired difference to its runs.

    python docs/scripts/car_park_table.py /tmp/cpd [/tmp/cph]
"""
import json
import sys

import numpy as np


def table(prefix: str) -> np.ndarray:
    rows = []
    for seed in range(10):
        m = json.load(open(f"{prefix}_{seed}/metrics.json"))
        lm, learned = m["landmarks"], m.get("noise_learned") or {}
        values = (seed, lm["n_matched"], lm["n_spurious"], lm["rmse"], lm["shape_error"], lm["frame_error"],
                  m["trajectory"]["rmse"])
        extra = ""
        if learned.get("enabled"):
            extra = " sr %.4g sb %.4g dof %.3g serial %.2f %.2f scale %.3g" % (
                learned["sigma_range"], learned["sigma_bearing"], learned["dof"], *learned["serial_correlation"],
                learned["motion_scale"])
        print("%d %d %d %.4g %.4g %.4g %.4g" % values + extra)
        rows.append(values)
    a = np.array(rows, dtype=float)[:, 1:]
    print("%s: 15/15 on %d seeds, spurious %s; rmse %.3f ± %.3f shape %.3f frame %.3f traj %.3f ± %.3f worst %.3f" % (
        prefix, int((a[:, 0] == 15).sum()), a[:, 1].astype(int).tolist(), a[:, 2].mean(), _se(a[:, 2]), a[:, 3].mean(),
        a[:, 4].mean(), a[:, 5].mean(), _se(a[:, 5]), a[:, 2].max()))
    return a


def _se(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x)))


if __name__ == "__main__":
    first = table(sys.argv[1])
    if len(sys.argv) > 2:
        second = table(sys.argv[2])
        d = first[:, 2] - second[:, 2]
        t = first[:, 5] - second[:, 5]
        print("paired first - second: rmse %+.3f ± %.3f, trajectory %+.3f ± %.3f" % (d.mean(), _se(d), t.mean(), _se(t)))
