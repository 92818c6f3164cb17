"""One robot of a fleet: the single-robot filter on the fleet's map (docs/METHOD.md, "Fleet mode").

:class:`FleetRobot` is :class:`~..filter.slam.OnlineEMSlam` unchanged (particles,
prediction, association, observation terms, noise learner, motion input) with the
landmark table and the M-step replaced by the fleet's shared ones (shared_map.py).
What would restart the map from one robot (a new pass, loading a map file) is
refused: the map is the fleet's (FleetSlam.load_map loads a file for every robot).
"""
from __future__ import annotations

import numpy as np

from ..config import SlamConfig
from ..filter.slam import OnlineEMSlam
from ..filter.warmup import WarmupReplay
from .shared_map import FleetLandmarkTable, RobotMStep


class FleetRobot(OnlineEMSlam):
    """A robot's particle filter whose map and M-step are the fleet's ``table`` and ``m_step``."""

    def __init__(self, config: SlamConfig, initial_pose, stamp: float | None, table: FleetLandmarkTable,
                 m_step: RobotMStep) -> None:
        self.shared_table = table
        self.shared_m_step = m_step
        self.fleet_warmup = WarmupReplay(False, 0, None)      # the fleet's, once it has made every robot
        super().__init__(config, initial_pose, stamp, m_step_factory=self._fleet_m_step)

    def __copy__(self) -> "FleetRobot":
        """A shallow copy (the fleet's warm-up replay) whose M-step factory is its own bound method,
        not the original's."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new._m_step_factory = new._fleet_m_step
        return new

    def _fleet_m_step(self, *_) -> RobotMStep:
        # A bound method, not a closure: a rollback's deep copy (pipeline/rollback.py) copies it
        # with the robot, so a reset after a restore still takes the fleet's current M-step.
        return self.shared_m_step

    def reset(self, initial_pose=None, stamp: float | None = None) -> None:
        """The robot's filter restarts; the map stays the fleet's (use :meth:`set_pose` to move it)."""
        super().reset(initial_pose, stamp)
        self._map = self.shared_table

    @property
    def initial_pose(self) -> np.ndarray:
        """(3,) where the filter last restarted (:meth:`reset`'s pose, to which ``reset()`` returns)."""
        return self._initial_pose.copy()

    def join_map(self, table: FleetLandmarkTable, m_step: RobotMStep, pose, stamp: float | None) -> None:
        """The fleet replaced its map: the filter restarts at ``pose`` (3,) on ``table`` and
        ``m_step`` with its time line at ``stamp`` (its last stamp when the fleet loads a map
        file, as a single robot's does; the start for the fleet's warm-up replay)."""
        self.shared_table, self.shared_m_step = table, m_step
        self.reset(pose, stamp)

    def set_pose(self, pose, std=None) -> None:
        """OnlineEMSlam.set_pose; the fleet's kept warm-up inputs no longer lead to this state."""
        super().set_pose(pose, std)
        self.fleet_warmup.discard()

    def start_new_pass(self, initial_pose=None, stamp: float | None = None) -> None:
        raise NotImplementedError("a fleet robot has no passes of its own: the map is the fleet's")

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        raise NotImplementedError("a fleet robot cannot load a map on its own: FleetSlam.load_map loads "
                                  "one for the whole fleet")
