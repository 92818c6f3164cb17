"""MRCLAM with every turn in place rescaled so that one rotation gain fits the robot's turns.

The robots deliver a different share of a commanded yaw rate turning in place than
turning while driving (docs/RESULTS.md, "What the data show": D9 R2 1.03 against 0.63).
This writes a copy of Datasets 1 and 9 in which the commanded yaw rate of every sample
with zero commanded speed is multiplied by the run's ratio of the two Vicon gains, so
that the one learned rotation gain of ``motion_gains`` describes both kinds of turn: the
upper bound of what a separate, learned in-place gain could bring (RESULTS.md, "Why the
defaults, and what did not work").

    python docs/scripts/mrclam_in_place_gain.py OUT [--data-dir ../shared/datasets/mrclam]
    online-em-slam-mrclam-benchmark --data-dir OUT --output OUT/bench --seconds 600 --seeds 0 1 \\
        --ids known --methods online_em
"""
from __future__ import annotations

import argparse
import tarfile
from pathlib import Path

# In-place / driving gains against Vicon (docs/scripts/mrclam_motion_truth.py, the table in
# RESULTS.md); runs that never turn in place are left as they are.
VICON_GAINS = {(1, 2): (0.76, 0.91), (1, 4): (0.89, 0.88), (1, 5): (0.57, 0.90),
               (9, 2): (1.03, 0.63), (9, 4): (1.00, 0.57), (9, 5): (1.00, 0.63)}
STANDING = 1e-3        # m/s: a commanded speed below this is a turn in place


def rescaled(text: str, ratio: float) -> tuple[str, int]:
    """Odometry.dat text with the yaw rate of in-place samples times ``ratio``; (text, samples changed)."""
    lines, changed = [], 0
    for line in text.splitlines():
        fields = line.split()
        if len(fields) == 3 and not line.lstrip().startswith("#"):
            t, v, w = fields
            if abs(float(v)) < STANDING and float(w) != 0.0:
                line, changed = f"{t}\t{v}\t{float(w) * ratio!r}", changed + 1
        lines.append(line)
    return "\n".join(lines) + "\n", changed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out")
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    args = parser.parse_args()
    out = Path(args.out)
    for dataset in (1, 9):
        with tarfile.open(Path(args.data_dir) / f"MRCLAM_Dataset{dataset}.tar.xz") as tar:
            tar.extractall(out, filter="data")
        for (d, robot), (in_place, driving) in VICON_GAINS.items():
            if d != dataset:
                continue
            path = out / f"MRCLAM_Dataset{d}" / f"Robot{robot}_Odometry.dat"
            text, changed = rescaled(path.read_text(), in_place / driving)
            path.write_text(text)
            print(f"Dataset {d} robot {robot}: {changed} in-place samples x {in_place / driving:.3f}")


if __name__ == "__main__":
    main()
