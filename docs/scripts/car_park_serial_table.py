"""Car Park seeds 0-9 (docs/measurements/car_park_learning.md, third pass): per seed the beacons,
errors and learned values of PREFIX_SEED run directories, their means, and the paired change
against the second pass's table in that file.

    python docs/scripts/car_park_serial_table.py /tmp/t10/cpb
"""
import json
import sys
from pathlib import Path

import numpy as np

MEASUREMENTS = Path(__file__).resolve().parents[1] / "measurements" / "car_park_learning.md"
HAND_TUNED = 0.162            # beacon RMSE of config/hand_tuned/car_park.yaml, seeds 0-9 (docs/RESULTS.md)


def second_pass() -> dict:
    text = MEASUREMENTS.read_text().split("## Re-measured after the motion-scale")[1].split("```")[1]
    rows = [line.split() for line in text.strip().splitlines()]
    return {int(f[0]): (float(f[3]), float(f[6])) for f in rows if f[0].isdigit()}


def main(prefix: str) -> None:
    rows = []
    for seed in range(10):
        m = json.load(open(f"{prefix}_{seed}/metrics.json"))
        lm, learned = m["landmarks"], m["noise_learned"]
        rows.append((seed, lm["n_matched"], lm["n_spurious"], lm["rmse"], lm["shape_error"], lm["frame_error"],
                     m["trajectory"]["rmse"], learned["sigma_range"], learned["sigma_bearing"],
                     *learned["serial_correlation"], learned["motion_scale"]))
        print("%d %d %d %.4g %.4g %.4g %.4g %.4g %.4g %.3f %.3f %.4g" % rows[-1])
    a = np.array([r[3:7] for r in rows])

    def se(x):
        return x.std(ddof=1) / np.sqrt(len(x))
    print("mean rmse %.3f ± %.3f shape %.3f frame %.3f traj %.3f ± %.3f worst %.3f"
          % (a[:, 0].mean(), se(a[:, 0]), a[:, 1].mean(), a[:, 2].mean(), a[:, 3].mean(), se(a[:, 3]), a[:, 0].max()))
    before = second_pass()
    d = a[:, 0] - np.array([before[s][0] for s in range(10)])
    dt = a[:, 3] - np.array([before[s][1] for s in range(10)])
    print("paired this - previous pass: rmse %+.3f ± %.3f, trajectory %+.3f ± %.3f" % (d.mean(), se(d), dt.mean(), se(dt)))
    print("hand-tuned %.3f: ratio %.3f" % (HAND_TUNED, a[:, 0].mean() / HAND_TUNED))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "/tmp/cpb")
