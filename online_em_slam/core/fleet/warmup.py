"""The fleet's warm-up replay (docs/METHOD.md, "Fleet mode"): every robot's warm-up filtered
again, on a new map, once every robot's learned noise is in use.

A single robot replays its own warm-up (filter/warmup.py).  A fleet robot cannot: its
first pass's factors are in the shared map already, and restarting its filter alone
would count its warm-up twice.  So the fleet keeps the inputs of all robots in the order
it received them; once every robot's noise learner has every learned value in use, the
map and every robot's filter restart at the robots' start poses, each learner starts from
its learned values, held through the replay (NoiseLearner.held), and the kept inputs are
fed again in their order.  Once.
"""
from __future__ import annotations

from contextlib import ExitStack

from ..filter.warmup import WarmupReplay, learned_start


class FleetWarmupReplay(WarmupReplay):
    """The inputs of every robot since the start, as (method, stamp, (robot, value)), and the
    replay.  ``start`` is the robots' start poses (R, 3)."""

    def due(self, robots) -> bool:
        """Inputs are kept and every robot's learner has every learned quantity in use."""
        return self.inputs is not None and all(robot._noise.all_in_use for robot in robots)

    def replay(self, fleet) -> None:
        """Restart ``fleet``'s map and robots at the start and feed the kept inputs again, each
        robot's learner starting from, and held at, its learned values; the drop counts stay
        the first pass's (the replayed inputs were counted already)."""
        robots = [fleet.robot(r) for r in range(fleet.n_robots)]
        learned = [learned_start(robot._noise) for robot in robots]
        drops = [dict(robot.drops) for robot in robots]
        inputs, self.inputs = self.inputs, None
        fleet.restart_map(self.start, from_start=True)
        with ExitStack() as held:
            for robot, values in zip(robots, learned):
                robot._noise.start_from(*values)
                held.enter_context(robot._noise.held())
            for method, stamp, (r, value) in inputs:
                getattr(robots[r], method)(stamp, value)
        for robot, counts in zip(robots, drops):
            robot.drops.clear()
            robot.drops.update(counts)
            robot._warmup.replayed = True          # reported per robot (learned_noise)
        self.replayed = True
