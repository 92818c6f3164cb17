"""The warm-up replay: the warm-up's inputs filtered again once the learned noise is in use.

The warm-up runs under the configured noise, and the map's frame set then would
stay (docs/METHOD.md, "Noise learned online", warm-up replay).  :class:`WarmupReplay`
keeps the estimator's inputs from its start; once every learned quantity is in
use, a new estimator starts at the initial pose, its noise learner from the
learned values (held while the warm-up is filtered again), and is fed the kept
inputs; once it has every input the estimator received, it becomes the estimator.
Once.  Before that, once, the same for the calibration of the motion input
(``replay_on_calibration``): when a learned motion gain comes into use, the
inputs so far are filtered again with the gains known and the values in use
then, and the kept inputs go on growing for the warm-up replay.  And once after it, when the
serial correlation's decay is learned and was not known yet when the warm-up replay started
(``NoiseLearner.serial_known``): a few early pairs of sightings fix it poorly, and the early map,
filtered under it, would keep their weights (docs/METHOD.md, "A correlation that decays").
With ``growth`` g > 1 (``replay_growth``) the inputs are kept on after that and filtered again
from the start each time they have grown g-fold since the last replay started: values that came
into use at a transient (a motion gain decided just before the warm-up replay) leave their mark
on the map only until the next replay (docs/METHOD.md, "Replays as the inputs grow").
A fleet (core/fleet/warmup.py) replays all its robots' inputs together, in the same way.

Offline the new estimator is fed everything at once, inside the input that made the
replay due.  A live node cannot stop that long (a fleet's replay on MRCLAM is most
of a minute), so it sets ``replay_in_slices`` on the estimator and feeds the replay
a few inputs at a time between its inputs (``advance``); the estimator it publishes
meanwhile goes on under the first pass.  Either way the replayed estimator sees the
same inputs in the same order, so it is the same once it takes over.

A replay filters the past again, so its poses are the estimate of the past trajectory
from then on: the poses it had after each scan it used (``trajectories``, per robot, of the
last replay taken over), which a node republishes as its path and the offline runner
scores beside the trajectory as it was published.
"""
from __future__ import annotations

import copy
from collections import Counter

import numpy as np


def learned_start(learner) -> tuple:
    """What a noise learner restarts from in a replay (NoiseLearner.start_from's arguments):
    the motion scales' estimates, not the ones in use, which move towards the estimates at a
    bounded rate and would filter the replay's first steps at the start values."""
    return learner.noise_config(), learner.scale_estimate, learner.gains_known(), learner.scales_estimate.copy()


def calibrated_start(learner) -> tuple:
    """What a noise learner restarts from in the calibration replay: the values in use, the
    motion gains known by then.  The rest is not learned yet: its estimates are the first
    pass's, made at the wrong gains."""
    return learner.noise_config(), learner.scale_in_use, learner.gains_known(), learner.scales_in_use.copy()


class WarmupReplay:
    """The inputs since the start (``inputs``, None once there is nothing to replay) and the replay.

    ``inputs`` only grows while kept: a rollback (pipeline/rollback.py) shares the list
    instead of copying it (the estimator names it in ``append_only_lists``).
    ``replaying``: the new estimator while it catches up (None before and after).
    """

    def __init__(self, keep: bool, max_inputs: int, start, calibrate: bool = False, growth: float = 0.0) -> None:
        self.inputs: list | None = [] if keep else None
        self.max_inputs = max_inputs
        self.start = start              # where the estimator restarts (see _restarted)
        self.replayed = False
        self.calibrate = calibrate      # replay once when a motion gain comes into use first
        self.calibrated = False
        self._calibrating = False       # the replay under way is the calibration's
        self._serial_pending = False    # the serial decay was not known when the warm-up replay started
        self.replaying = None
        self._fed = 0                   # kept inputs fed to ``replaying``
        self._warmup_length = 0         # the inputs up to the one that made the replay due
        self.growth = growth            # replay again once the kept inputs grew by this factor (> 1)
        self.replays = 0                # replays taken over so far, of every kind (learned_noise reports it)
        self.needless = False           # every value came into use where the warm-up began: no replay
        self.trajectories: dict[int, np.ndarray] = {}     # per robot, (n, 4) of the last replay taken over
        self._poses: dict[int, list] = {}              # per robot, the replay under way's poses

    def record(self, method: str, stamp: float, value) -> None:
        """One input as the estimator received it (its method name, stamp and value)."""
        inputs = self.inputs
        if inputs is None:
            return
        if len(inputs) >= self.max_inputs and self.replaying is None:
            self.inputs = None          # too long a warm-up to keep: no replay
            return
        inputs.append((method, stamp, value))

    def discard(self) -> None:
        """The inputs so far no longer lead to the estimator's state: no replay (or no more)."""
        self.inputs = None
        self.replaying = None

    def due(self, learner) -> bool:
        """Inputs are kept, no replay runs, and every quantity the noise learner learns is in use,
        or (the calibration replay, once) a learned motion gain is; after the warm-up replay, the
        serial decay is known (once) or the inputs have grown ``growth``-fold since the last.
        Every value in use where the warm-up began (the data cannot tell them apart): :meth:`skip`."""
        if self.inputs is None or self.replaying is not None:
            return False
        if self.replayed:               # kept for the serial decay's replay, or for growth
            if self._serial_pending:    # set when the warm-up replay started, cleared by the next
                return learner.serial_known
            return self.grown()
        in_use = learner.all_in_use
        if in_use and not learner.differs_from_start():
            self.skip()
            return False
        return in_use or (self.calibrate and not self.calibrated and learner.calibration_in_use)

    def skip(self) -> None:
        """The learned values came into use and the data cannot tell them from those the warm-up
        began under (NoiseLearner.differs_from_start): filtered again, the warm-up would be drawn
        again, not filtered better.  No replay, and none as the inputs grow."""
        self.discard()
        self.needless = True

    def grown(self) -> bool:
        """The kept inputs have grown ``growth``-fold since the last replay started (growth on)."""
        return self.growth > 1.0 and len(self.inputs) >= self.growth * self._warmup_length

    def replay(self, estimator, in_slices: bool = False) -> None:
        """Start the replay for ``estimator``: all of it now, or (``in_slices``) in :meth:`advance`.
        The calibration's while some learned value is not in use yet, else the warm-up's."""
        learners = self._learners(estimator)
        self._calibrating = not self.replayed and self.calibrate and not all(learner.all_in_use for learner in learners)
        self._serial_pending = not (self.replayed or self._calibrating) and not all(
            learner.serial_known for learner in learners)
        try:
            self.replaying = self._restarted(estimator)
        except Exception:  # noqa: BLE001 - as a failure while feeding (advance): counted, the first pass goes on
            self._failed(estimator)
            return
        self._fed, self._warmup_length, self._poses = 0, len(self.inputs), {}
        if not in_slices:
            self.advance(estimator)

    def advance(self, estimator, max_inputs: int | None = None) -> bool:
        """Feed the replay up to ``max_inputs`` kept inputs (None: all); once it has every input,
        it becomes ``estimator``.  True while it is still catching up."""
        replaying = self.replaying
        if replaying is None:
            return False
        end = len(self.inputs) if max_inputs is None else min(len(self.inputs), self._fed + max_inputs)
        try:
            for method, stamp, value in self.inputs[self._fed:end]:
                self._feed(replaying, method, stamp, value)
                self._fed += 1
                if method == "add_observations":
                    robot, estimate = self._pose_after(replaying, value)
                    self._poses.setdefault(robot, []).append(
                        (stamp if estimate.stamp is None else estimate.stamp, *estimate.mean[:3]))
                if self._fed == self._warmup_length:
                    # The warm-up's values were learned from these inputs; later ones teach again.
                    for learner in self._learners(replaying):
                        learner.holding = False
        except Exception:  # noqa: BLE001 - a failure no check caught: the first pass goes on, counted
            self._failed(estimator)
            return False
        if self._fed < len(self.inputs):
            return True
        self._take_over(estimator, replaying)
        return False

    def _keep_poses(self) -> None:
        """The poses of the replay taking over become the past trajectory's estimate."""
        self.trajectories = {robot: np.asarray(rows, dtype=float) for robot, rows in self._poses.items()}
        self._poses = {}

    def _failed(self, estimator) -> None:
        """A replay that raised, starting or feeding: no replay any more, counted.  Not re-raised: a
        rollback of the input that made the replay due would make it due again at the next input,
        and fail every input after it (an injected fault in the restart dropped 281 of MRCLAM D9
        R4's scans that way)."""
        self.discard()
        self._drops(estimator)["warmup_replay_failed"] += 1

    # ------------------------------------------------------------------ the estimator's kind
    # A single robot (OnlineEMSlam); core/fleet/warmup.py has the fleet's.
    def _restarted(self, estimator):
        """A new estimator of ``estimator``'s configuration at the start, its learner started
        from and held at the learned values, keeping no inputs of its own."""
        learned = (calibrated_start if self._calibrating else learned_start)(estimator._noise)
        fresh = copy.copy(estimator)        # the configuration shared; reset rebinds every state
        fresh.drops = Counter()
        fresh.reset(*self.start)
        fresh._warmup.discard()
        fresh._noise.start_from(*learned)
        fresh._noise.holding = True
        return fresh

    @staticmethod
    def _learners(estimator) -> list:
        return [estimator._noise]

    @staticmethod
    def _drops(estimator):
        return estimator.drops

    @staticmethod
    def _feed(estimator, method: str, stamp: float, value) -> None:
        getattr(estimator, method)(stamp, value)

    @staticmethod
    def _pose_after(estimator, value) -> tuple:
        """(robot, its PoseEstimate) after the observations ``value`` were fed."""
        return 0, estimator.pose()

    def _take_over(self, estimator, replayed) -> None:
        """``replayed`` becomes ``estimator`` (the same object: whoever holds it goes on with it);
        the drop counts stay the estimator's, which counted every input once."""
        drops = estimator.drops
        estimator.__dict__.clear()
        estimator.__dict__.update(replayed.__dict__)
        estimator.drops = estimator._input.drops = drops   # the motion input counts into it too
        self.replays += 1
        self._keep_poses()
        if self._calibrating:           # the warm-up replay is still to come: the kept inputs go on
            self.replaying, self._calibrating, self.calibrated = None, False, True
            estimator._warmup = self
            return
        if self._serial_pending or self.growth > 1.0:   # once more: the kept inputs go on
            self.replaying, self.replayed = None, True
            estimator._warmup = self
            return
        estimator._warmup.replayed, estimator._warmup.calibrated = True, self.calibrated
        estimator._warmup.replays, estimator._warmup.trajectories = self.replays, self.trajectories
