"""Fleet mode's inputs: one input pipeline per robot, all feeding the one FleetSlam.

:class:`FleetInputs` takes the place of :class:`~.inputs.Inputs` on the node: it
holds one :class:`~.fleet_robot.FleetRobotIO` per robot (its subscriptions, its
own stamp-ordered merge, so one robot's silence holds no other back, its
publishers and map -> its odom) and answers the node, the services and
/diagnostics for all of them: the input streams are watched together (one
:class:`~.input_watch.InputWatch`), the queues and loads are summed, drops are
reported per robot (``dropped.<robot>.<reason>``), and so are the inputs received
(``inputs.<robot>``).  In the distributed mode (``local_robot``) it holds only the
robot this node drives.
"""
from __future__ import annotations

from collections import Counter

from .fleet_names import fleet_names, initial_poses
from .fleet_robot import FleetRobotIO
from .input_watch import InputWatch


class FleetPipelines:
    """The robots' pipelines as the node's ``inputs.pipeline``."""

    def __init__(self, robots: list[FleetRobotIO]) -> None:
        self.robots = robots

    def __len__(self) -> int:
        return sum(len(io.inputs.pipeline) for io in self.robots)

    @property
    def drops(self) -> Counter:
        out: Counter = Counter()
        for io in self.robots:
            out.update(io.drops())
        return out

    @property
    def newest(self) -> float | None:
        stamps = [io.inputs.pipeline.newest for io in self.robots if io.inputs.pipeline.newest is not None]
        return max(stamps) if stamps else None

    @property
    def max_load(self) -> float:
        return max(io.inputs.pipeline.max_load for io in self.robots)

    def current_load(self, now: float | None = None) -> float:
        """The node's share of wall time on inputs: the robots' loads together (one executor)."""
        return sum(io.inputs.pipeline.current_load(now) for io in self.robots)

    def forget_time_line(self) -> None:
        for io in self.robots:
            io.inputs.pipeline.forget_time_line()

    def checkpoint(self) -> None:
        for io in self.robots:
            io.inputs.pipeline.checkpoint()


class FleetFrames:
    """The robots' frame checks as the node's ``inputs.frames``."""

    def __init__(self, robots: list[FleetRobotIO]) -> None:
        self.robots = robots

    @property
    def uses_tf(self) -> bool:
        return any(io.inputs.frames.uses_tf for io in self.robots)

    def diagnostics(self) -> dict:
        out: Counter = Counter()
        for io in self.robots:
            out.update(io.inputs.frames.diagnostics())
        return dict(out)


class FleetInputs:
    """Every robot's inputs and outputs (``node``: OnlineEmSlamNode, whose ``slam`` is a FleetEstimate)."""

    def __init__(self, node, diagnostics) -> None:
        self.node = node
        estimate = node.slam
        poses, names = initial_poses(node.settings), fleet_names(node.settings)
        self.robots = [FleetRobotIO(node, r, names[r], estimate.feeds[r], poses[r], diagnostics)
                       for r in estimate.driven]
        self.watch = InputWatch()
        self._share_watch()
        self.pipeline = FleetPipelines(self.robots)
        self.frames = FleetFrames(self.robots)

    def _share_watch(self) -> None:
        for io in self.robots:
            io.inputs.watch = self.watch

    def received(self) -> dict[str, int]:
        """Each robot's well-formed inputs received (the node's ``inputs``, per robot)."""
        return {io.name: io.diagnostics.inputs for io in self.robots}

    @property
    def corrected(self) -> Counter:
        out: Counter = Counter()
        for io in self.robots:
            out.update(io.inputs.corrected)
        return out

    # ------------------------------------------------------------------ lifecycle and settings
    def subscribe(self) -> None:
        for io in self.robots:
            io.inputs.subscribe()

    def unsubscribe(self) -> None:
        for io in self.robots:
            io.inputs.unsubscribe()
        self.watch = InputWatch()
        self._share_watch()

    def apply_settings(self, settings) -> None:
        for io in self.robots:
            io.apply_settings(settings)

    def restart(self, estimate) -> None:
        """The node made a new fleet (a reset): every robot feeds it."""
        for io in self.robots:
            io.restart(estimate.feeds[io.view.index])

    # ------------------------------------------------------------------ periodic
    def on_clock_jump(self, jump) -> None:
        for io in self.robots:
            io.inputs.on_clock_jump(jump)

    def housekeeping(self) -> None:
        for io in self.robots:
            io.inputs.housekeeping()

    def publishers(self, stream) -> int:
        return self.node.count_publishers(stream.topic)

    def publish_map(self) -> None:
        """The one landmark map and markers (when any robot changed it), then every robot's path."""
        node = self.node
        with node.lock:
            if any(io.outputs.map_dirty for io in self.robots):
                node.outputs.map_dirty = True
        node.outputs.publish_map()
        for io in self.robots:
            io.outputs.publish_map()

    def clear_paths(self) -> None:
        """Every robot's path starts again (a loaded map restarted each robot's filter)."""
        for io in self.robots:
            io.outputs.path.clear()
            io.outputs.map_dirty = True

    def republish_transform(self) -> None:
        for io in self.robots:
            io.outputs.republish_transform()
