"""One robot of a fleet: the single-robot filter on the fleet's map (docs/METHOD.md, "Fleet mode").

:class:`FleetRobot` is :class:`~..filter.slam.OnlineEMSlam` unchanged (particles,
prediction, association, observation terms, noise learner, motion input) with the
landmark table and the M-step replaced by the fleet's shared ones (shared_map.py).
What would restart the map from one robot (a new pass, loading a map file) is
refused: the map is the fleet's.
"""
from __future__ import annotations

from ..config import SlamConfig
from ..filter.slam import OnlineEMSlam
from .shared_map import FleetLandmarkTable, RobotMStep


class FleetRobot(OnlineEMSlam):
    """A robot's particle filter whose map and M-step are the fleet's ``table`` and ``m_step``."""

    def __init__(self, config: SlamConfig, initial_pose, stamp: float | None, table: FleetLandmarkTable,
                 m_step: RobotMStep) -> None:
        self.shared_table = table
        super().__init__(config, initial_pose, stamp, m_step_factory=lambda *_: m_step)

    def reset(self, initial_pose=None, stamp: float | None = None) -> None:
        """The robot's filter restarts; the map stays the fleet's (use :meth:`set_pose` to move it)."""
        super().reset(initial_pose, stamp)
        self._map = self.shared_table

    def start_new_pass(self, initial_pose=None, stamp: float | None = None) -> None:
        raise NotImplementedError("a fleet robot has no passes of its own: the map is the fleet's")

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        raise NotImplementedError("a fleet robot cannot load a map: the map is the fleet's")
