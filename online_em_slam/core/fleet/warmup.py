"""The fleet's warm-up replay (docs/METHOD.md, "Fleet mode"): every robot's warm-up filtered
again, on a new map, once every robot's learned noise is in use.

A single robot replays its own warm-up (filter/warmup.py).  A fleet robot cannot: its
first pass's factors are in the shared map already, and restarting its filter alone
would count its warm-up twice.  So the fleet keeps the inputs of all robots in the order
it received them; once every robot's noise learner has every learned value in use, a new
fleet starts (an empty map, every robot at its start pose), each learner from its
learned values, held through the warm-up, and is fed the kept inputs in their order
(all at once, or in slices as filter/warmup.py describes) until it takes over.  Once, or
with ``growth`` g > 1 (``replay_growth``) again each time the kept inputs have grown g-fold
since the last replay started, as a single robot's replays do.
"""
from __future__ import annotations

import copy
from collections import Counter

from ..filter.warmup import WarmupReplay, learned_start


class FleetWarmupReplay(WarmupReplay):
    """The inputs of every robot since the start, as (method, stamp, (robot, value)), and the
    replay.  ``start`` is the robots' start poses (R, 3)."""

    def due(self, robots) -> bool:
        """Inputs are kept, no replay runs, and every robot's learner has every learned quantity in
        use (and some robot's differ from those its warm-up began under: else :meth:`skip`); after
        that replay, the inputs have grown ``growth``-fold since the last one started."""
        if self.inputs is None or self.replaying is not None:
            return False
        if self.replayed:
            return self.grown()
        if not all(r._noise.all_in_use for r in robots):
            return False
        if not any(r._noise.differs_from_start() for r in robots):
            self.skip()
            for robot in robots:
                robot._warmup.needless = True       # reported per robot (learned_noise)
            return False
        return True

    def _restarted(self, fleet):
        learned = [learned_start(robot._noise) for robot in fleet._robots]
        fresh = copy.copy(fleet)            # the configuration shared; restart_map rebinds the map
        fresh._robots = [copy.copy(robot) for robot in fleet._robots]
        fresh._warmup = FleetWarmupReplay(False, 0, self.start)
        for robot, values in zip(fresh._robots, learned):
            robot.drops = Counter()
            robot.fleet_warmup = fresh._warmup
        fresh.restart_map(self.start, from_start=True)       # every robot's filter reset on it
        for robot, values in zip(fresh._robots, learned):
            robot._noise.start_from(*values)
            robot._noise.holding = True
        return fresh

    @staticmethod
    def _drops(fleet):
        return fleet.robot(0).drops          # the fleet's drops are the robots' (FleetSlam.drops sums them)

    @staticmethod
    def _learners(fleet) -> list:
        return [robot._noise for robot in fleet._robots]

    @staticmethod
    def _feed(fleet, method: str, stamp: float, value) -> None:
        robot, value = value
        getattr(fleet, method)(robot, stamp, value)

    @staticmethod
    def _pose_after(fleet, value) -> tuple:
        return value[0], fleet.pose(value[0])

    def _take_over(self, fleet, replayed) -> None:
        drops = [robot.drops for robot in fleet._robots]
        fleet.__dict__.clear()
        fleet.__dict__.update(replayed.__dict__)
        self.replays += 1
        self._keep_poses()
        for robot, counts in zip(fleet._robots, drops):
            robot.drops = robot._input.drops = counts       # the motion input counts into it too
            robot._warmup.replayed, robot._warmup.replays = True, self.replays   # reported per robot (learned_noise)
        if self.growth > 1.0:           # the kept inputs go on, to be filtered again as they grow
            self.replaying, self.replayed = None, True
            fleet._warmup = self
            for robot in fleet._robots:
                robot.fleet_warmup = self
            return
        fleet._warmup.replayed, fleet._warmup.replays = True, self.replays
        fleet._warmup.trajectories = self.trajectories
