"""The batch optimum with a camera error correlation that decays with the viewpoint's change
(docs/RESULTS.md, "UTIAS MRCLAM", variant 52): does that model fit the data better than one
correlation per scan pair?

    OMP_NUM_THREADS=1 python docs/scripts/mrclam_viewpoint_batch.py [--c0 0.96 0.65] [--length 0.4 0.25] \
        [--turn 1.2] -- BAG --params config/mrclam.yaml --params RUN/noise.yaml --output OUT --seed 0 --no-plot

``online-em-slam run ... --method batch`` (offline/batch.py, the maximum a posteriori of online
EM's model) with each observation's R inflated as the serial correlation does it, (1 + c) / (1 - c)
per component (models/observation.py, information_noise), but with c its own: c = c0 exp(-v / l)
for the range and the bearing, v the viewpoint's change since the same landmark's previous kept
sighting, the robot's displacement plus ``--turn`` metres per radian of heading change (dead
reckoning between the two scans); a landmark's first sighting has c = 0.  The run's own learned
serial correlation is set aside (the file's noise.serial_correlation is overridden with 0).
Defaults: fitted by eye to the Vicon table of docs/scripts/mrclam_correlation_by_travel.py.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np


def viewpoint_changes(problem, turn: float) -> np.ndarray:
    """(P,) v of each observation since its landmark's previous one (inf for a first sighting),
    from the dead-reckoned pose variables (distances between them do not depend on the start)."""
    from online_em_slam.baselines.gtsam_batch import compose

    poses = [np.zeros(3)]
    for k, increment in enumerate(problem.increments, start=1):
        poses.append(np.zeros(3) if k in problem.chain_starts else compose(poses[-1], increment))
    poses = np.array(poses)
    v = np.full(problem.obs_id.size, np.inf)
    last: dict[int, int] = {}
    for p, (landmark, k) in enumerate(zip(problem.obs_id.tolist(), problem.obs_pose.tolist())):
        previous = last.get(landmark)
        if previous is not None:
            step = poses[k] - poses[previous]
            turned = abs((step[2] + np.pi) % (2 * np.pi) - np.pi)
            v[p] = float(np.hypot(step[0], step[1]) + turn * turned)
        last[landmark] = k
    return v


def inflated(R: np.ndarray, v: np.ndarray, c0, length) -> np.ndarray:
    """R (P, 2, 2) with component j scaled by (1 + c_j) / (1 - c_j), c_j = c0_j exp(-v / l_j)."""
    c = np.asarray(c0)[None] * np.exp(-v[:, None] / np.asarray(length)[None])        # (P, 2)
    f = np.sqrt((1.0 + c) / (1.0 - c))
    return R * f[:, :, None] * f[:, None, :]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--c0", type=float, nargs=2, default=(0.96, 0.65), metavar=("RANGE", "BEARING"))
    parser.add_argument("--length", type=float, nargs=2, default=(0.4, 0.25), metavar=("RANGE", "BEARING"))
    parser.add_argument("--turn", type=float, default=1.2, help="metres of viewpoint change per radian turned")
    parser.add_argument("run_args", nargs=argparse.REMAINDER, help="-- then online-em-slam run's arguments")
    args = parser.parse_args(argv)
    from online_em_slam.offline import batch_run, cli

    collect = batch_run.collect_problem

    def collect_problem(events, config, *rest, **kwargs):
        config = replace(config, noise=replace(config.noise, serial_correlation=(0.0, 0.0)))
        problem = collect(events, config, *rest, **kwargs)
        problem.obs_R = inflated(problem.obs_R, viewpoint_changes(problem, args.turn), args.c0, args.length)
        return problem

    batch_run.collect_problem = collect_problem
    run_args = args.run_args[1:] if args.run_args[:1] == ["--"] else args.run_args
    return cli.main(["run", *run_args, "--method", "batch"])


if __name__ == "__main__":
    sys.exit(main())
