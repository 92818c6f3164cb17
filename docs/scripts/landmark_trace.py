"""A run's map fitted onto the surveyed landmarks every few seconds: where a map bends and
which landmarks stay off (docs/RESULTS.md, "UTIAS MRCLAM", D9 R3's gap to EKF-SLAM).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python docs/scripts/landmark_trace.py BAG OUT \
        [--every 4] [--landmarks 15] -- [online-em-slam run options: --params ..., --seed, --method]

Runs ``online-em-slam run BAG --output OUT --no-plot ...`` with the estimator's map read after
every observation message at least ``--every`` seconds after the last read (the estimator the
run ends with: a warm-up or calibration replay's estimator once it takes over, never the one
catching up). Each map is moved by its best rigid fit onto the bag's surveyed landmarks (the
shape error of docs/RESULTS.md). Prints one row per read: seconds since the first, the replays
done so far (calibration, warm-up), the shape RMSE, the landmarks mapped and the error of each
``--landmarks`` id; writes OUT/trace.json. One BLAS thread, as the benchmarks use, to repeat a
benchmark's run bit for bit.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from online_em_slam.offline import cli, runner
from online_em_slam.offline.evaluation import fitted_onto


def rigid_fit_errors(ids: np.ndarray, positions: np.ndarray, truth: dict[int, np.ndarray]) -> dict[int, float]:
    """Each surveyed landmark's error (m) after the best rigid 2-D fit of the map onto the survey
    (the evaluation's fit, offline/evaluation.py)."""
    keep = [k for k, i in enumerate(ids) if int(i) in truth]
    if len(keep) < 3:
        return {}
    surveyed = np.array([truth[int(ids[k])] for k in keep])
    residual = fitted_onto(positions[keep], positions[keep], surveyed) - surveyed
    return {int(ids[k]): float(np.hypot(*residual[j])) for j, k in enumerate(keep)}


class MapReads:
    """The map of the estimator the run makes, read every ``every`` seconds of stamps."""

    def __init__(self, every: float) -> None:
        self.every, self.reads, self.main, self.next, self.inputs = every, [], None, None, None

    def install(self) -> None:
        make, read_inputs = runner.make_estimator, cli.read_inputs

        def making(method, config, pose):
            estimator = make(method, config, pose)
            self.main = estimator
            self._wrap(type(estimator))
            return estimator

        def reading(*args, **kwargs):           # the run's bag inputs: the survey comes with them
            self.inputs = read_inputs(*args, **kwargs)
            return self.inputs
        runner.make_estimator, cli.read_inputs = making, reading

    def _wrap(self, cls) -> None:
        add = cls.add_observations
        reads = self

        def add_observations(estimator, stamp, observations):
            report = add(estimator, stamp, observations)
            if estimator is reads.main:       # a replay's estimator is another object until it takes over
                reads.read(estimator, float(stamp))
            return report
        cls.add_observations = add_observations

    def read(self, estimator, stamp: float) -> None:
        if self.next is not None and stamp < self.next:
            return
        self.next = stamp + self.every
        landmarks = estimator.landmarks()
        warmup = getattr(estimator, "_warmup", None)
        replays = (bool(warmup.calibrated), bool(warmup.replayed)) if warmup is not None else None
        self.reads.append((stamp, landmarks.ids.copy(), landmarks.positions.copy(), replays))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    own, run_args = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, [])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("output")
    parser.add_argument("--every", type=float, default=4.0, help="seconds between map reads")
    parser.add_argument("--landmarks", type=int, nargs="*", default=[], help="ids whose error to print")
    args = parser.parse_args(own)
    reads = MapReads(args.every)
    reads.install()
    code = cli.main(["run", args.bag, "--output", args.output, "--no-plot", *run_args])
    inputs = reads.inputs
    if inputs.landmarks is None or inputs.landmark_ids is None:
        raise SystemExit(f"{args.bag}: no surveyed landmarks with ids to fit onto")
    truth = {int(i): xy for i, xy in zip(inputs.landmark_ids, inputs.landmarks)}
    rows = trace_rows(reads.reads, truth, args.landmarks)
    (Path(args.output) / "trace.json").write_text(json.dumps(rows))
    return code


def trace_rows(reads: list, truth: dict[int, np.ndarray], picked: list[int]) -> list[dict]:
    """Each map read fitted onto the survey; one printed line per read."""
    rows = []
    start = reads[0][0] if reads else 0.0
    for stamp, ids, positions, replays in reads:
        errors = rigid_fit_errors(ids, positions, truth)
        shape = float(np.sqrt(np.mean(np.square(list(errors.values()))))) if errors else float("nan")
        rows.append({"t": stamp - start, "replays": replays, "shape": shape, "mapped": len(errors), "errors": errors})
        chosen = " ".join(f"{i}: {errors.get(i, float('nan')):.2f}" for i in picked)
        print(f"{stamp - start:7.1f} s  replays {replays}  shape {shape:.3f}  mapped {len(errors):2d}  {chosen}")
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
