"""The one map of a fleet as each robot's filter sees it (docs/METHOD.md, "Fleet mode").

The robots' filters (robot.py) keep the single-robot code path of
filter/slam.py: they add, prune and associate landmarks through a
:class:`~..mapping.landmarks.LandmarkTable` and hand every filter step to an
M-step piece.  Here both are the fleet's own: :class:`FleetLandmarkTable` is the
one table, whose creation steps and tentative timeouts count on the fleet clock,
and :class:`RobotMStep` is a robot's handle on the one observed-information M-step
(em/observed.py with R key poses), which closes the robot's segments against its
own key block.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..em.observed import ObservedInformationEM
from ..em.step import FilterStepData
from ..mapping.landmarks import LandmarkTable


@dataclass
class FleetLandmarkTable(LandmarkTable):
    """The fleet's landmark table: a landmark created by one robot is associated by all.

    ``clock()`` is the fleet's step count, the most filter steps any robot has made:
    the creation step of a landmark and its tentative timeout (``stale``) count on it,
    whichever robot created or prunes the landmark.  With one robot it is the robot's
    own step count, as in the single-robot table.
    """

    clock: Callable[[], int] = field(default=lambda: 0, repr=False, compare=False)

    def add(self, positions: np.ndarray, ids: np.ndarray, step: int, prunable=True) -> np.ndarray:
        return super().add(positions, ids, self.clock(), prunable)

    def stale(self, step: int, confirm_observations: int, tentative_timeout: int) -> np.ndarray:
        return super().stale(self.clock(), confirm_observations, tentative_timeout)


class RobotMStep:
    """Robot ``robot``'s view of the fleet's one M-step: the MStep interface of em/step.py.

    :meth:`update` adds the robot's step to its own open segment, closes it against the
    robot's key block at its segment end and solves the joint system: the map moves for
    everyone, the returned correction is this robot's.  :meth:`restart_pose` touches
    only the robot's key block.  Everything else (rows, covariances, the map file's
    arrays) is the shared M-step's.
    """

    def __init__(self, shared: ObservedInformationEM, robot: int) -> None:
        self.shared = shared
        self.robot = robot

    def update(self, data: FilterStepData, table: LandmarkTable) -> np.ndarray | None:
        return self.shared.update(data, table, self.robot)

    def restart_pose(self, pose: np.ndarray, pose_std, table: LandmarkTable, weights: np.ndarray | None = None) -> None:
        self.shared.restart_pose(pose, pose_std, table, weights, self.robot)

    def add_landmarks(self, count: int) -> None:
        self.shared.add_landmarks(count)

    def keep_landmarks(self, keep: np.ndarray) -> None:
        self.shared.keep_landmarks(keep)

    def covariances(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        return self.shared.covariances(rows)

    def covariances_given_pose(self, rows: np.ndarray) -> np.ndarray:
        return self.shared.covariances_given_pose(rows, self.robot)

    def map_covariances(self) -> np.ndarray:
        return self.shared.map_covariances()

    def saved_arrays(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        return self.shared.saved_arrays(theta)

    def restore(self, arrays: dict[str, np.ndarray], theta: np.ndarray) -> None:
        self.shared.restore(arrays, theta)
