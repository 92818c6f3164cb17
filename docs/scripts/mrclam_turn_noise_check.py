"""MRCLAM: does the learned turning noise predict the commanded heading's error against Vicon?

Over windows of T seconds (half overlapping), the heading the commands give (yaw rate times
the learned rotation gain, turns in place times the in-place gain, plus the learned turn per
metre times the speed, each command held from its stamp plus the learned dead time) is compared
with Vicon's change of heading; each error is divided by the standard deviation the learned
noise gives it: the turning noise sigma^2 + (sigma_relative u)^2 per noise_reference_period,
integrated as continuous-time white noise (models/motion.py). A consistent model gives z's root
mean square near 1 at every T; above 1 the noise under-predicts the drift. Vicon's yaw glitches
(steps faster than 4 rad/s) are dropped.

    python docs/scripts/mrclam_turn_noise_check.py DATASET ROBOT NOISE_YAML [--data-dir ...]
        [--seconds 600] [--windows 5 10 30 60]

NOISE_YAML: a run's learned noise.yaml (online-em-slam run's output).
"""
import argparse
from pathlib import Path

import numpy as np
import yaml

from online_em_slam.datasets.mrclam.benchmark import dataset_source
from online_em_slam.datasets.mrclam.dataset import load_mrclam
from online_em_slam.core.models.motion import IN_PLACE_SPEED

MAX_RATE = 4.0      # rad/s: faster Vicon yaw steps are glitches


def learned_turning(path):
    """(rotation gain, in-place gain, dead time, sigma, sigma_relative, reference period, turn per metre
    times the speed gain) of a noise.yaml."""
    with open(path) as f:
        p = yaml.safe_load(f)["/**"]["ros__parameters"]
    gain = float(p.get("motion.rotation_gain", 1.0))
    in_place = float(p.get("motion.rotation_in_place_gain", 0.0)) or gain
    drift = float(p.get("motion.turn_per_meter", 0.0)) * float(p.get("motion.translation_gain", 1.0))
    return (gain, in_place, float(p.get("motion.control_delay", 0.0)), float(p["motion.sigma_steering"]),
            float(p.get("motion.sigma_steering_relative", 0.0)), float(p.get("motion.noise_reference_period", 0.2)),
            drift)


def clean_yaw(run):
    """Vicon's yaw (n,) accumulated from its steps, glitches (steps faster than MAX_RATE) left out."""
    t, yaw = run.ground_truth_times, run.ground_truth_poses[:, 2]
    step = np.angle(np.exp(1j * np.diff(yaw)))
    step[np.abs(step) / np.maximum(np.diff(t), 1e-3) > MAX_RATE] = 0.0
    return np.concatenate([[yaw[0]], yaw[0] + np.cumsum(step)])


def window_z(run, learned, T):
    """Per window of T s: (heading error of the commands, its model standard deviation)."""
    gain, in_place, delay, sigma, relative, period, drift = learned
    t = run.odometry_times + delay
    u = run.odometry_w
    rate = u * np.where(np.abs(run.odometry_v) < IN_PLACE_SPEED, in_place, gain) + drift * run.odometry_v
    dt = np.diff(t, append=t[-1] + np.median(np.diff(t)))
    heading = np.concatenate([[0.0], np.cumsum(rate * dt)])[:-1]
    variance = np.concatenate([[0.0], np.cumsum((sigma ** 2 + (relative * u) ** 2) * period * dt)])[:-1]
    gt, yaw = run.ground_truth_times, clean_yaw(run)
    errors, stds = [], []
    for a in np.arange(max(t[0], gt[0]) + 5.0, min(t[-1], gt[-1]) - T, T / 2):
        b = a + T
        true = np.interp(b, gt, yaw) - np.interp(a, gt, yaw)
        commanded = np.interp(b, t, heading) - np.interp(a, t, heading)
        errors.append(commanded - true)
        stds.append(np.sqrt(np.interp(b, t, variance) - np.interp(a, t, variance)))
    return np.array(errors), np.array(stds)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=int)
    parser.add_argument("robot", type=int)
    parser.add_argument("noise_yaml")
    parser.add_argument("--data-dir", default="../shared/datasets/mrclam")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--windows", type=float, nargs="+", default=[5.0, 10.0, 30.0, 60.0])
    args = parser.parse_args()
    run = load_mrclam(dataset_source(Path(args.data_dir), args.dataset), args.robot, args.seconds)
    learned = learned_turning(args.noise_yaml)
    print(f"D{args.dataset} R{args.robot}: gain {learned[0]:.3f}, in place {learned[1]:.3f}, dead time "
          f"{learned[2]:.3f} s, turn per metre {learned[6]:+.4f} rad/m, turning noise {learned[3]:.4f} + "
          f"{learned[4]:.3f} |u|")
    for T in args.windows:
        e, s = window_z(run, learned, T)
        z = e / np.maximum(s, 1e-12)
        print(f"  T = {T:4.0f} s: error rms {np.sqrt(np.mean(e ** 2)):.3f} rad, model std rms "
              f"{np.sqrt(np.mean(s ** 2)):.3f}, z rms {np.sqrt(np.mean(z ** 2)):.2f}, "
              f"|z| > 3: {np.mean(np.abs(z) > 3):.2f}")


if __name__ == "__main__":
    main()
