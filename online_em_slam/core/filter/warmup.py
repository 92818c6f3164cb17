"""The warm-up replay: the warm-up's inputs filtered again once the learned noise is in use.

The warm-up runs under the configured noise, and the map's frame set then would
stay (docs/METHOD.md, "Noise learned online", warm-up replay).  :class:`WarmupReplay`
keeps the estimator's inputs from its start; once every learned quantity is in
use, it restarts the estimator at its initial pose, starts the noise learner
from the learned values and feeds the kept inputs again.  Once.
"""
from __future__ import annotations


def learned_start(learner) -> tuple:
    """What a noise learner restarts from in a replay (NoiseLearner.start_from's arguments):
    the motion scales' estimates, not the ones in use, which move towards the estimates at a
    bounded rate and would filter the replay's first steps at the start values."""
    return learner.noise_config(), learner.scale_estimate, learner.gains_known(), learner.scales_estimate.copy()


class WarmupReplay:
    """The inputs since the start (``inputs``, None once there is nothing to replay) and the replay.

    ``inputs`` only grows while kept: a rollback (pipeline/rollback.py) shares the list
    instead of copying it (the estimator names it in ``append_only_lists``).
    """

    def __init__(self, keep: bool, max_inputs: int, start: tuple) -> None:
        self.inputs: list | None = [] if keep else None
        self.max_inputs = max_inputs
        self.start = start              # (initial pose, stamp) to restart at
        self.replayed = False

    def record(self, method: str, stamp: float, value) -> None:
        """One input as the estimator received it (its method name, stamp and value)."""
        inputs = self.inputs
        if inputs is None:
            return
        if len(inputs) >= self.max_inputs:
            self.inputs = None          # too long a warm-up to keep: no replay
            return
        inputs.append((method, stamp, value))

    def discard(self) -> None:
        """The inputs so far no longer lead to the estimator's state: no replay."""
        self.inputs = None

    def due(self, learner) -> bool:
        """Inputs are kept and every quantity the noise learner learns is in use."""
        return self.inputs is not None and learner.all_in_use

    def replay(self, estimator) -> None:
        """Restart ``estimator`` (an :class:`OnlineEMSlam`) at the start and filter the kept
        inputs again, the noise learner starting from the learned values; the drop
        counts stay those of the first pass (the replayed inputs were counted already)."""
        learned = learned_start(estimator._noise)
        inputs, drops = self.inputs, dict(estimator.drops)
        estimator.reset(*self.start)
        fresh = estimator._warmup
        fresh.discard()
        estimator._noise.start_from(*learned)
        with estimator._noise.held():                   # the warm-up's values, learned from these inputs
            for method, stamp, value in inputs:
                getattr(estimator, method)(stamp, value)
        estimator.drops.clear()
        estimator.drops.update(drops)
        fresh.replayed = True
