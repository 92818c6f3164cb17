"""The landmark survey checked against the robot's own measurements and ground-truth poses.

Each measurement of subject s, placed in the Vicon frame from the robot's ground-truth
pose at its time (x + r cos(yaw + b), y + r sin(yaw + b)), lands near the surveyed
position of s: within the camera's noise, a few centimetres for the median of the
placements.  In Dataset 1 it does not for subjects 11 and 17, on every robot: the
median placement of each lies 6 m from its own survey entry and within centimetres of
the other's, so the survey file (or Barcodes.dat) swaps the two labels.  A map
scored by id would be charged 6 m for two landmarks every method places right.

:func:`survey_relabelling` finds such label errors from the data alone: a subject
whose placements sit far from its own entry and on another subject's entry, the
relation a permutation among those subjects.  The loader applies it to the survey
(``MrclamRun.survey_relabelled``) and the converter reports it.  Only the ground
truth changes; the measurements keep the labels the robot read.
"""
from __future__ import annotations

import numpy as np

#: A subject's median placement this far from its own survey entry is a label error ...
OWN_ENTRY_MISS = 1.0
#: ... when it lies this close to another subject's entry (metres) ...
OTHER_ENTRY_HIT = 0.5
#: ... and rests on at least this many measurements.
MIN_MEASUREMENTS = 10


def ground_truth_at(run, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground-truth pose (x, y, yaw), each (n,), interpolated at ``times`` (yaw unwrapped first)."""
    gt_t, gt = run.ground_truth_times, run.ground_truth_poses
    return (np.interp(times, gt_t, gt[:, 0]), np.interp(times, gt_t, gt[:, 1]),
            np.interp(times, gt_t, np.unwrap(gt[:, 2])))


def median_placements(run) -> dict[int, np.ndarray]:
    """Median Vicon-frame position (2,) of each measured subject's measurements, placed from
    the ground-truth pose at the measurement time (:func:`ground_truth_at`)."""
    t, gt_t = run.measurement_times, run.ground_truth_times
    if len(t) == 0 or len(gt_t) < 2:
        return {}
    inside = (t >= gt_t[0]) & (t <= gt_t[-1])
    x, y, yaw = ground_truth_at(run, t)
    px = x + run.measurement_range * np.cos(yaw + run.measurement_bearing)
    py = y + run.measurement_range * np.sin(yaw + run.measurement_bearing)
    placements = {}
    for subject in np.unique(run.measurement_subjects):
        hit = inside & (run.measurement_subjects == subject)
        if np.count_nonzero(hit) >= MIN_MEASUREMENTS:
            placements[int(subject)] = np.array([np.median(px[hit]), np.median(py[hit])])
    return placements


def survey_relabelling(run) -> dict[int, int]:
    """{measured subject: survey subject whose entry it is} for the label errors found
    (empty when the survey agrees with the measurements).  Only a set of errors that forms
    a permutation of survey entries is returned; anything else is left as it is."""
    entries = {int(s): xy for s, xy in zip(run.landmark_subjects, run.landmark_xy)}
    moves = {}
    for subject, placed in median_placements(run).items():
        if subject not in entries or np.hypot(*(placed - entries[subject])) <= OWN_ENTRY_MISS:
            continue
        other = min(entries, key=lambda s: np.hypot(*(placed - entries[s])))
        if other != subject and np.hypot(*(placed - entries[other])) <= OTHER_ENTRY_HIT:
            moves[subject] = other
    if sorted(moves) != sorted(moves.values()):
        return {}
    return moves


def relabelled_survey(subjects: np.ndarray, moves: dict[int, int]) -> np.ndarray:
    """Survey subject labels (m,) with entry ``moves[s]`` relabelled s."""
    entry_of = {entry: subject for subject, entry in moves.items()}
    return np.array([entry_of.get(int(s), int(s)) for s in subjects], dtype=subjects.dtype)
