"""Unknown-id association checked against the barcodes: where duplicates come from.

Runs online EM on a known-id MRCLAM bag with the ids hidden from the estimator (every
observation associated by likelihood, as with ``--unknown-ids``), and scores each decision
against the barcode the camera read: per landmark the barcode most of its observations
carry (its owner) and the share that do (purity); barcodes owning more than one landmark
(duplicates); the share of observations associated right, wrong or dropped. For every
duplicate's creation it prints why the existing landmark was not taken: the squared
Mahalanobis distance d2 of the observation to it, the predicted and the Vicon-true
(range, bearing), the gate's standard deviations, the mean pose's error against Vicon and
the particle cloud's spread (docs/RESULTS.md, "UTIAS MRCLAM", unknown ids).

    python docs/scripts/mrclam_association_oracle.py BAG [--params config/mrclam.yaml ...] [--seed 0]

BAG: ``online-em-slam-convert mrclam BAG --data-dir ... --robot K --seconds 600`` (known ids).
"""
import argparse
import collections

import numpy as np

from online_em_slam.core.filter.association import predicted_measurements
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.models.observation import (innovation, mahalanobis_2d, noise_covariance,
                                                    predict_observation)
from online_em_slam.core.types import Observations
from online_em_slam.core.weighted import weighted_pose_mean
from online_em_slam.offline.runner import choose_initial_pose, feed, read_inputs
from online_em_slam.parameters.yaml_file import config_from_params, load_params


class Oracle:
    """The record of one run: the barcodes of each scan (by stamp) and every decision, as
    (stamp, barcode, landmark id or -1 dropped, created). Kept outside the estimator, whose
    state the input pipeline copies for its rollback; cleared when the estimator restarts
    (the warm-up replay filters the same scans again)."""

    def __init__(self, inputs, config):
        self.inputs, self.config = inputs, config
        self.barcodes, self.log, self.first_landmark, self.start = {}, [], {}, None

    def restart(self):
        self.log, self.first_landmark = [], {}

    def decided(self, est, stamp, obs, sensor, prior_weights, obs_idx, rows, n_before):
        codes = self.barcodes[stamp]
        for o, row in zip(obs_idx, rows):
            code, landmark, created = int(codes[o]), int(est._map.ids[row]), bool(row >= n_before)
            self.log.append((stamp, code, landmark, created))
            if created and code in self.first_landmark:
                self.explain(est, stamp, obs, o, sensor, prior_weights, code)
            elif created:
                self.first_landmark[code] = landmark
        for o in sorted(set(range(len(codes))) - set(obs_idx.tolist())):
            self.log.append((stamp, int(codes[o]), -1, False))

    def explain(self, est, stamp, obs, o, sensor, prior_weights, code):
        """Why the first landmark of this barcode was not taken."""
        rows = np.flatnonzero(est._map.ids == self.first_landmark[code])
        if not rows.size:                    # pruned meanwhile
            return
        w = prior_weights / prior_weights.sum()
        R = noise_covariance(est._noise.noise_config(), obs.ranges[[o]])
        theta = est._map.theta[rows[:1]]
        mean, S = predicted_measurements(theta, sensor, w, est._m_step.covariances(rows[:1]),
                                         self.config.association, R)
        y = np.array([[obs.ranges[o], obs.bearings[o]]])
        d2, _ = mahalanobis_2d(innovation(y, mean)[:, None, :], S)
        truth = self.truth_pose(stamp)
        surveyed = self.inputs.landmarks[list(self.inputs.landmark_ids).index(code)]
        h_true = predict_observation(truth[None], surveyed[None])[0]
        pose = weighted_pose_mean(sensor, w)
        spread = np.sqrt(np.diag(np.cov(sensor.T, aweights=w)))
        print(f"duplicate t={stamp - self.start:6.1f} s barcode {code}: d2 {float(d2.ravel()[0]):6.1f}  "
              f"y ({y[0, 0]:.2f}, {y[0, 1]:+.3f})  predicted ({mean[0, 0]:.2f}, {mean[0, 1]:+.3f})  "
              f"true ({h_true[0]:.2f}, {h_true[1]:+.3f})  gate std ({np.sqrt(S[0, 0, 0, 0]):.3f}, "
              f"{np.sqrt(S[0, 0, 1, 1]):.3f})  pose error ({pose[0] - truth[0]:+.2f}, {pose[1] - truth[1]:+.2f}, "
              f"{np.angle(np.exp(1j * (pose[2] - truth[2]))):+.3f})  spread ({spread[0]:.3f}, {spread[1]:.3f}, "
              f"{spread[2]:.3f})  landmark error {np.hypot(*(theta[0] - surveyed)):.2f} m")

    def truth_pose(self, stamp):
        k = min(np.searchsorted(self.inputs.gt_pose_times, stamp), len(self.inputs.gt_poses) - 1)
        return self.inputs.gt_poses[k]


def oracle_estimator(config, pose, oracle: Oracle) -> OnlineEMSlam:
    """OnlineEMSlam that sees no ids and reports its associations to ``oracle``."""

    class HiddenIds(OnlineEMSlam):
        def reset(self, *args, **kwargs):
            oracle.restart()
            return super().reset(*args, **kwargs)

        def add_observations(self, stamp, obs):
            if np.any(obs.ids >= 0):                     # from the bag, not the warm-up replay
                oracle.barcodes[stamp] = obs.ids.copy()
                oracle.start = stamp if oracle.start is None else oracle.start
            self._oracle_stamp = stamp
            return super().add_observations(stamp, Observations(obs.ranges, obs.bearings, None, obs.range_std,
                                                                obs.bearing_std))

        def _associate(self, obs, sensor, prior_weights, report):
            n_before = len(self._map.ids)
            obs_idx, rows = super()._associate(obs, sensor, prior_weights, report)
            oracle.decided(self, self._oracle_stamp, obs, sensor, prior_weights, obs_idx, rows, n_before)
            return obs_idx, rows

    return HiddenIds(config, initial_pose=pose)


def summary(log):
    by_landmark = collections.defaultdict(collections.Counter)
    for _, code, landmark, _ in log:
        if landmark >= 0:
            by_landmark[landmark][code] += 1
    owner = {lm: counts.most_common(1)[0][0] for lm, counts in by_landmark.items()}
    for lm in sorted(by_landmark):
        n = sum(by_landmark[lm].values())
        print(f"landmark {lm:3d}  barcode {owner[lm]:3d}  observations {n:4d}  purity {by_landmark[lm][owner[lm]] / n:.2f}")
    owners = collections.Counter(owner.values())
    print("barcodes with more than one landmark:", {k: v for k, v in sorted(owners.items()) if v > 1})
    right = sum(1 for _, code, lm, _ in log if lm >= 0 and owner[lm] == code)
    dropped = sum(1 for _, _, lm, _ in log if lm < 0)
    n = len(log)
    print(f"observations {n}: associated right {right / n:.2f}, wrong {(n - right - dropped) / n:.2f}, "
          f"dropped {dropped / n:.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag")
    parser.add_argument("--params", nargs="+", default=["config/mrclam.yaml"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    values = {}
    for path in args.params:
        values.update(load_params(path))
    config, settings = config_from_params(values, {"filter.seed": args.seed})
    inputs = read_inputs(args.bag, settings)
    initial = choose_initial_pose("auto", inputs, config, settings, values)
    oracle = Oracle(inputs, config)
    estimator = oracle_estimator(config, initial.pose, oracle)
    feed(estimator, inputs)
    summary(oracle.log)
    print("drops", dict(estimator.drops))


if __name__ == "__main__":
    main()
