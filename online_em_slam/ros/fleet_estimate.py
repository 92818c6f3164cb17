"""The fleet's estimate as the node's ``slam`` in fleet mode (diagnostics, services, the map timer).

The node-level parts that read ``node.slam`` (the map publisher, /diagnostics, the
map-file services) see the fleet through :class:`FleetEstimate`: the one map, the
newest stamp of any robot, the drops of every robot's filter under
``<robot>.<reason>``.  Each robot's own pose, particles and inputs go through its
:class:`~online_em_slam.pipeline.fleet.RobotView` (fleet_robot.py).

In the distributed mode (``local_robot``) the node drives one robot of the fleet: only
that robot's filter is fed and reported, its segments go out (:meth:`outgoing`) and the
other nodes' come in (:meth:`fold_remote`, through the fleet's rollback so that a failing
input undone later keeps them), see segment_link.py.
"""
from __future__ import annotations

import secrets
from collections import Counter

from ..core.fleet.slam import FleetSlam
from ..pipeline.fleet import robot_views


class FleetEstimate:
    """``fleet`` (FleetSlam) and its robots' feeds; ``robots``: the robots' names, in order;
    ``local_robot``: the one this node drives (distributed mode), empty: every robot."""

    def __init__(self, config, initial_poses, robots: tuple[str, ...], local_robot: str = "") -> None:
        self.fleet = FleetSlam(config, initial_poses)
        self.robots = tuple(robots)
        self.feeds = robot_views(self.fleet)
        self.driven = (self.robots.index(local_robot),) if local_robot else tuple(range(len(self.robots)))
        # Distributed mode (segment_link.py): this estimator's session, drawn at its start so that
        # the other nodes tell its messages numbered from 1 again from duplicates, and the
        # (session, sequence) of each other robot's message folded last.
        self.session = secrets.randbits(63)
        self.received: dict[str, tuple[int, int]] = {}
        if local_robot:
            self.fleet.share_segments()

    @property
    def distributed(self) -> bool:
        return len(self.driven) < len(self.robots)

    def outgoing(self) -> list:
        """The segment messages this node's robot closed since the last call (distributed mode)."""
        return self.fleet.outgoing()

    def fold_remote(self, message) -> None:
        """Another node's segment message, through the fleet's rollback (a restore re-applies it)."""
        self.feeds[0].shared.call("fold_remote", message)

    def take_lost(self) -> int:
        """Inputs the fleet's rollback lost applying them again after a failure (pipeline/rollback.py)."""
        return self.feeds[0].shared.take_lost()

    @property
    def config(self):
        return self.fleet.config

    @property
    def replay_in_slices(self) -> bool:
        return self.fleet.replay_in_slices

    @replay_in_slices.setter
    def replay_in_slices(self, value: bool) -> None:
        self.fleet.replay_in_slices = value

    def advance_replay(self, max_inputs: int) -> bool:
        return self.fleet.advance_replay(max_inputs)

    @property
    def last_stamp(self) -> float | None:
        """The newest stamp any robot's filter has reached."""
        stamps = [self.fleet.robot(r).last_stamp for r in self.driven]
        stamps = [s for s in stamps if s is not None]
        return max(stamps) if stamps else None

    @property
    def drops(self) -> Counter:
        out: Counter = Counter()
        for r in self.driven:
            name = self.robots[r]
            out.update({f"{name}.{reason}": n for reason, n in self.fleet.robot(r).drops.items() if n})
        return out

    def landmarks(self, confirmed_only: bool = False):
        return self.fleet.landmarks(confirmed_only)

    def robot_diagnostics(self) -> dict:
        """Per driven robot, under ``<robot>.``: its ESS, last stamp and learned noise (/diagnostics)."""
        values = {}
        for r in self.driven:
            name = self.robots[r]
            robot = self.fleet.robot(r)
            values[f"{name}.ess"] = float(robot.effective_sample_size)
            values[f"{name}.last_stamp"] = robot.last_stamp if robot.last_stamp is not None else -1.0
            learned = robot.learned_noise()
            if learned["enabled"]:
                values.update({f"{name}.noise_learned.{k}": v for k, v in learned.items()
                               if k not in ("enabled", "learning")})
        return values

    def learned_noise(self) -> dict:
        """The first driven robot's learned noise (each robot learns its own)."""
        return self.fleet.robot(self.driven[0]).learned_noise()

    def save_map(self, path: str) -> None:
        """The joint map as a single robot's map file (FleetSlam.save_map)."""
        self.fleet.save_map(path)

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        """A map file (a fleet's or a single robot's) becomes the one map; every robot restarts on
        it, robot 0 relocalising around the file's pose, the others around their own (FleetSlam.load_map).
        Not in the distributed mode: the other nodes' maps would not follow."""
        if self.distributed:
            raise ValueError("a distributed fleet node (local_robot) cannot load a map file: the other "
                             "robots' nodes would not load it")
        self.fleet.load_map(path, restore_pose)

    def set_pose(self, pose, std=None) -> None:
        raise NotImplementedError("fleet mode: set a robot's pose with initial_poses")
