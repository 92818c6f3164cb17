"""Undo a failed input: the estimator put back to its state before that input.

An exception inside an estimator's step (a value no check caught, a bug) can
leave half-updated state behind, and then every later step fails on it.  So
the estimator's state is copied every ``period`` filter steps (the calls in
FILTER_STEPS), or after MAX_REPLAY calls of any kind, and the calls since are kept;
when a call raises, the copy is put back and those calls are applied again.  The
estimators are deterministic given their random generator, which the copy holds, so
this reproduces the state just before the failing input exactly; the failing input
is lost (the caller counts it).

The period counts filter steps, not inputs: a copy costs 0.5 ms (Car Park) to a few
ms (Victoria Park's 237 landmarks), a control input a few hundredths of a ms, and the
bound that matters on a failure is the filter steps to apply again.  Counted by
inputs, Victoria Park's nine controls per scan made a copy every few scans: about 1 s
of the 4.5 s its feed loop spends outside the filter steps.  One call can hold far more
than a step: the input that makes the warm-up replay due filters every input so far
again inside it (offline), so a copy is also taken once the calls since the last one
took ``MAX_REAPPLY_SECONDS``; a failure soon after would otherwise do the replay again.

An input applied once applies again from the same copy; one that raises all the same
(a failure that depends on more than the inputs, such as memory) ends the re-application:
the copy is put back with the inputs before it, and it and the inputs after it are lost,
counted in ``lost`` (the feeder's ``reapply_failed``).  Lists that only ever
grow (the warm-up log of ``OnlineEMSlam``, named by the estimator's
``append_only_lists``) are shared, not copied, and cut back to their length at the
copy when it is put back.
"""
from __future__ import annotations

import copy
import time

DEFAULT_PERIOD = 64            # filter steps between copies
FILTER_STEPS = frozenset({"add_observations", "fold_remote"})
MAX_REPLAY = 1024              # calls between copies at most (motion input without scans)
MAX_REAPPLY_SECONDS = 1.0      # time spent in the calls between copies at most
QUERIES = frozenset({"pose"})  # calls that change nothing: not inputs, never lost


class Rollback:
    """Applies inputs to ``estimator`` so that a failing one leaves no trace."""

    def __init__(self, estimator, period: int = DEFAULT_PERIOD) -> None:
        self.estimator = estimator
        self.period = int(period)
        self.lost = 0                  # inputs lost because applying them again raised (see restore)
        self.checkpoint()

    def call(self, method: str, *args):
        """``estimator.method(*args)``; on an exception the state before it is restored, then it re-raises."""
        started = time.perf_counter()
        try:
            result = getattr(self.estimator, method)(*args)
        except Exception:
            self.restore()
            raise
        self._since.append((method, args))
        self._steps += method in FILTER_STEPS
        self._busy += time.perf_counter() - started
        if self._steps >= self.period or len(self._since) >= MAX_REPLAY or self._busy >= MAX_REAPPLY_SECONDS:
            self.checkpoint()
        return result

    def checkpoint(self) -> None:
        """Take the estimator's present state as the one to return to (call after any outside change)."""
        self._shared = self._shared_lists()
        self._saved = copy.deepcopy(self.estimator.__dict__, self._memo())
        self._since: list = []
        self._steps, self._busy = 0, 0.0

    def restore(self) -> None:
        """Put the checkpoint back and re-apply the inputs that followed it; where one of them
        raises, the checkpoint with the inputs before it, the rest lost (``lost``)."""
        applied = len(self._since)
        while (reapplied := self._put_back(self._since[:applied])) < applied:
            applied = reapplied         # fewer each time: ends, at the checkpoint itself at worst
        self.lost += sum(method not in QUERIES for method, _ in self._since[applied:])
        del self._since[applied:]
        self._steps = sum(method in FILTER_STEPS for method, _ in self._since)

    def take_lost(self) -> int:
        """The inputs lost since the last call (the feeder counts them)."""
        lost, self.lost = self.lost, 0
        return lost

    def _put_back(self, calls: list) -> int:
        """The checkpoint, then ``calls`` applied again: how many applied before one raised."""
        for values, length in self._shared.values():
            del values[length:]
        self.estimator.__dict__.clear()
        self.estimator.__dict__.update(copy.deepcopy(self._saved, self._memo()))
        for applied, (method, args) in enumerate(calls):
            try:
                getattr(self.estimator, method)(*args)
            except Exception:  # noqa: BLE001 - it applied once: a failure beyond the inputs, counted
                return applied
        return len(calls)

    def _shared_lists(self) -> dict:
        names = getattr(self.estimator, "append_only_lists", ())
        lists = (getattr(self.estimator, name, None) for name in names)
        return {id(values): (values, len(values)) for values in lists if isinstance(values, list)}

    def _memo(self) -> dict:
        """What the copy shares: the growing lists, and the estimator itself for any back-reference."""
        memo = {key: values for key, (values, _) in self._shared.items()}
        memo[id(self.estimator)] = self.estimator
        return memo
