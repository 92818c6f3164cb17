"""The warm-up replay fed between the node's inputs (docs/NODE.md, "Noise learned online").

Offline the replay runs at once, inside the input that made it due.  A node cannot
stop that long (the replay refilters everything since the start: seconds for one
robot, most of a minute for a fleet of five on MRCLAM), so its estimator replays in
slices (``replay_in_slices``, core/filter/warmup.py) and a timer feeds it for a
bounded time per tick; the executor serves the inputs in between, the published
estimate goes on under the first pass, and the replayed estimator takes over once it
has caught up with every input, the same as the replay made at once.
"""
from __future__ import annotations

import time

PERIOD = 0.05        # s between ticks (steady clock)
BUDGET = 0.02        # s of replay per tick at most: 40 % of a core while it catches up
SLICE = 16           # inputs per call into the estimator: a few ms


class WarmupReplayFeeder:
    """The node's timer callback that advances its estimator's warm-up replay."""

    def __init__(self, node) -> None:
        self.node = node
        self.catching_up = False

    def tick(self) -> None:
        node = self.node
        with node.lock:
            estimator = node.slam                   # OnlineEMSlam, or FleetEstimate
            deadline = time.monotonic() + BUDGET
            catching_up = estimator.advance_replay(SLICE)
            while catching_up and time.monotonic() < deadline:
                catching_up = estimator.advance_replay(SLICE)
            if catching_up and not self.catching_up:
                node.get_logger().info("the warm-up replay started: it is fed between the inputs")
            if self.catching_up and not catching_up:
                # The replayed estimator has taken over (or failed, counted): a failing input must
                # not undo that.
                node.inputs.pipeline.checkpoint()       # one robot's pipeline, or every robot's
                node.get_logger().info("the warm-up replay has ended (the pose may jump)")
            self.catching_up = catching_up
