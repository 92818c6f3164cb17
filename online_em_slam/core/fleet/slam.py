"""Fleet mode of the estimator: R robots, one map (docs/METHOD.md, "Fleet mode").

Each robot has its own particle filter (its pose), motion input, noise learner
and initial pose (robot.py: the single-robot filter); the map is one parameter of
every robot's hidden Markov model, so one observed-information system over
[dx_key_1 .. dx_key_R; theta] (em/segment_factors.py) takes every robot's
segments, and one landmark table serves every robot's association: a landmark
created by one robot is associated by all (known ids: the same id is the same
landmark; unknown ids: the gates see the shared map).

Each robot's inputs arrive in its own time order and are checked per robot; one
robot's silence holds no other back.  A robot's filter step closes its own
segment; the map is solved at the segment ends of any robot.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np

from ..config import SlamConfig
from ..em.observed import ObservedInformationEM
from ..mapping import mapfile, persistence
from ..types import LandmarkMap, Observations, PoseEstimate, StepReport
from .robot import FleetRobot
from .shared_map import FleetLandmarkTable, RobotMStep
from .warmup import FleetWarmupReplay
from ..em.segment_message import SegmentMessage


class FleetSlam:
    """Particle online EM SLAM of R robots sharing one landmark map.

    ``initial_poses`` (R, 3): each robot's start in the map frame (its prior, as the
    single robot's ``initial_pose``).  Robot r's filter draws from ``filter.seed + r``.

    Not in fleet mode: the complete-data M-step (``em.m_step = complete``: its
    statistics are smoothed over one robot's particles; a ValueError).  The warm-up
    replay (``noise_learning.replay_warmup``) is the fleet's, not each robot's: the
    map and every robot restart once every robot's learned noise is in use
    (warmup.py).
    """

    #: Lists that only grow, which a rollback (pipeline/rollback.py) shares instead of copying.
    append_only_lists = ("_warmup_log",)

    def __init__(self, config: SlamConfig | None = None, initial_poses=((0.0, 0.0, 0.0),),
                 stamp: float | None = None) -> None:
        config = (config or SlamConfig()).validate()
        if config.em.m_step != "observed":
            raise ValueError(f"fleet mode needs em.m_step = observed, got {config.em.m_step!r}: the "
                             "complete-data M-step keeps statistics smoothed over one robot's particles")
        poses = np.asarray(initial_poses, dtype=float)
        if poses.ndim != 2 or poses.shape[1] != 3 or not poses.shape[0] or not np.all(np.isfinite(poses)):
            raise ValueError(f"initial_poses must be R >= 1 finite (x, y, yaw) rows, got shape {poses.shape}")
        self.config = replace(config, noise_learning=replace(config.noise_learning, replay_warmup=False))
        self._m_step = ObservedInformationEM(self.config, poses)
        self._map = FleetLandmarkTable(clock=self._clock)
        self._robots = [FleetRobot(self._robot_config(r), poses[r], stamp, self._map, RobotMStep(self._m_step, r))
                        for r in range(poses.shape[0])]
        replay = config.noise_learning.replay_warmup and bool(self._robots[0]._noise.learn)
        self._start_stamp = stamp
        self.replay_in_slices = False       # a live node's choice (OnlineEMSlam.replay_in_slices)
        self._warmup = FleetWarmupReplay(replay, config.noise_learning.max_replay_inputs * len(poses), poses.copy(),
                                         growth=config.noise_learning.replay_growth)
        for robot in self._robots:
            robot.fleet_warmup = self._warmup

    @property
    def _warmup_log(self) -> list | None:
        """Every robot's inputs kept for the fleet's warm-up replay (None: none kept), owned by warmup.py."""
        return self._warmup.inputs

    def _robot_config(self, robot: int) -> SlamConfig:
        seed = self.config.filter.seed
        return replace(self.config, filter=replace(self.config.filter, seed=None if seed is None else seed + robot))

    def _clock(self) -> int:
        """The fleet's step count: the most filter steps any robot has made."""
        return max(robot.step_count for robot in self._robots)

    def robot(self, robot: int) -> FleetRobot:
        """Robot ``robot``'s filter (0 .. R-1): its ``drops``, ``learned_noise()``, ``effective_sample_size``."""
        if not 0 <= robot < len(self._robots):
            raise ValueError(f"robot {robot} is not in the fleet of {len(self._robots)}")
        return self._robots[robot]

    @property
    def n_robots(self) -> int:
        return len(self._robots)

    @property
    def step_count(self) -> int:
        """Filter steps of all robots together."""
        return sum(robot.step_count for robot in self._robots)

    @property
    def drops(self) -> Counter:
        """Every robot's dropped inputs, by reason."""
        return sum((robot.drops for robot in self._robots), Counter())

    # ------------------------------------------------------------------ inputs
    def add_control(self, robot: int, stamp: float, control) -> bool:
        """Robot ``robot``'s control, valid from ``stamp`` on (OnlineEMSlam.add_control)."""
        filter_ = self.robot(robot)
        self._warmup.record("add_control", stamp, (robot, control))
        return filter_.add_control(stamp, control)

    def add_odometry(self, robot: int, stamp: float, odom_pose) -> bool:
        """Robot ``robot``'s odometry-frame pose (OnlineEMSlam.add_odometry)."""
        filter_ = self.robot(robot)
        self._warmup.record("add_odometry", stamp, (robot, odom_pose))
        return filter_.add_odometry(stamp, odom_pose)

    def add_observations(self, robot: int, stamp: float, observations: Observations) -> StepReport:
        """Robot ``robot``'s scan: one filter step of its filter, its segment's factors to the
        shared map, the map solved at its segment end (OnlineEMSlam.add_observations); the
        fleet's replay once one is due (core/fleet/warmup.py)."""
        filter_ = self.robot(robot)
        self._warmup.record("add_observations", stamp, (robot, observations))
        report = filter_.add_observations(stamp, observations)
        if self._warmup.due(self._robots):
            self._warmup.replay(self, self.replay_in_slices)
        return report

    def advance_replay(self, max_inputs: int) -> bool:
        """With ``replay_in_slices``: feed the warm-up replay up to ``max_inputs`` inputs
        (OnlineEMSlam.advance_replay); True while it is still catching up."""
        return self._warmup.advance(self, max_inputs)

    def set_pose(self, robot: int, pose, std=None) -> None:
        """Put robot ``robot`` at ``pose``: only its key pose restarts (OnlineEMSlam.set_pose)."""
        self.robot(robot).set_pose(pose, std)

    def relocalise(self, robot: int, pose, std=None) -> None:
        """Robot ``robot`` is near ``pose`` on the fleet's map (OnlineEMSlam.relocalise)."""
        self.robot(robot).relocalise(pose, std)

    # ------------------------------------------------------------------ other nodes
    def share_segments(self) -> None:
        """From now on every segment this fleet closes is also kept for other nodes (:meth:`outgoing`):
        the distributed mode, one node per robot, each folding in the others' (:meth:`fold_remote`).
        No warm-up replay then: it would restart the map without the other nodes' segments."""
        self._m_step.outbox = []
        self._warmup.discard()

    def outgoing(self) -> list[SegmentMessage]:
        """The segment messages closed since the last call (empty unless :meth:`share_segments`)."""
        messages = self._m_step.outbox or []
        if self._m_step.outbox is not None:
            self._m_step.outbox = []
        return messages

    def fold_remote(self, message: SegmentMessage) -> None:
        """Another node's segment of robot ``message.robot`` into the map (a robot this node does not
        drive): its landmarks found by id, the ones new here added at the sender's estimates."""
        rows = self._rows_of(message.ids, message.theta)
        self._m_step.fold_remote(message, rows, self._map)
        if message.segment is not None:        # confirmed as this node's own observations confirm them
            np.add.at(self._map.n_obs, rows, message.segment.counts)
            self._map.confirmed[rows] |= self._map.n_obs[rows] >= self.config.association.confirm_observations

    def _rows_of(self, ids: np.ndarray, theta: np.ndarray) -> np.ndarray:
        row_of = {int(i): row for row, i in enumerate(self._map.ids.tolist())}
        new = np.array([int(i) not in row_of for i in ids.tolist()], dtype=bool)
        if new.any():
            added = self._map.add(theta[new], ids[new], 0)
            self._m_step.add_landmarks(added.size)
            row_of.update(zip(ids[new].tolist(), added.tolist()))
        return np.array([row_of[int(i)] for i in ids.tolist()], dtype=np.int64)

    # ------------------------------------------------------------------ outputs
    def pose(self, robot: int) -> PoseEstimate:
        return self.robot(robot).pose()

    def revised_trajectory(self, robot: int) -> np.ndarray | None:
        """OnlineEMSlam.revised_trajectory of ``robot``, from the fleet's last replay."""
        return self._warmup.trajectories.get(robot)

    def particles(self, robot: int) -> tuple[np.ndarray, np.ndarray]:
        return self.robot(robot).particles()

    # ------------------------------------------------------------------ map files
    def save_map(self, path: str) -> None:
        """Write the joint map as a single robot's map file (OnlineEMSlam.save_map): the map, its
        information and counts, with robot 0's pose and learned noise, so a single robot, the
        node or a fleet (:meth:`load_map`) loads it."""
        self._robots[0].save_map(path)

    def load_map(self, path: str, restore_pose: bool = True) -> None:
        """Replace the fleet's map by a map file's (one written by :meth:`save_map` or by a single
        robot, OnlineEMSlam.save_map: the same format); EM continues from its information and counts.

        The file's landmarks (theta (M, 2), ids, observation counts, confirmed flags) become the
        one table every robot associates against, each with its information (2, 2) as a prior
        of the shared M-step.  Every robot's filter restarts as a single robot's does on a load
        (its time line kept, the file's learned noise its noise learner's starting point).  The
        file holds one pose, the saving robot's, and no pose per robot; with ``restore_pose``:

        * robot 0 relocalises around the file's pose (a fleet saves robot 0's pose, a single
          robot its own);
        * every other robot relocalises around its current mean pose, which stays in the map
          frame the fleet shares;

        relocalising, a robot creates no landmark until its particles have narrowed
        (OnlineEMSlam.relocalise).  Without ``restore_pose`` every robot restarts at its
        initial pose and does not relocalise (OnlineEMSlam.load_map's ``restore_pose=False``).

        The file is validated completely before anything changes; on any error (MapFileError,
        a ValueError naming the file) the fleet, its map and its robots stay as they were.
        """
        loaded = mapfile.read_map(path, max_landmarks=self.config.association.max_landmarks)
        poses = self._poses_after_load(loaded, restore_pose)
        snapshot = [(owner, dict(owner.__dict__)) for owner in (self, *self._robots)]
        try:
            self.restart_map(poses)
            persistence.restore_map(self._map, self._m_step, loaded)
            for robot, pose in zip(self._robots, poses):
                robot.resume_from_file(loaded, pose if restore_pose else None)
            self._warmup.discard()
        except BaseException:
            # Every change above rebinds attributes of the fleet or its robots (new table,
            # M-step and filter state), so the shallow copies put everything back.
            for owner, state in snapshot:
                owner.__dict__.clear()
                owner.__dict__.update(state)
            raise

    def _poses_after_load(self, loaded: dict[str, np.ndarray], restore_pose: bool) -> np.ndarray:
        """(R, 3) where each robot restarts on a loaded map (see :meth:`load_map`)."""
        if not restore_pose:
            return np.array([robot.initial_pose for robot in self._robots])
        poses = np.array([robot.pose().mean for robot in self._robots])
        poses[0] = persistence.saved_pose(loaded)
        return poses

    def restart_map(self, poses: np.ndarray, from_start: bool = False) -> None:
        """An empty table and M-step with key poses ``poses`` (R, 3); every robot's filter restarts
        on them at its pose, its time line kept (``from_start``: at the fleet's start stamp, for
        the warm-up replay)."""
        self._m_step = ObservedInformationEM(self.config, poses)
        self._map = FleetLandmarkTable(clock=self._clock)
        for r, robot in enumerate(self._robots):
            robot.join_map(self._map, RobotMStep(self._m_step, r), poses[r],
                           self._start_stamp if from_start else robot.last_stamp)

    def landmarks(self, confirmed_only: bool = False) -> LandmarkMap:
        """The fleet's map theta with covariances and observation counts (every robot's)."""
        return self._robots[0].landmarks(confirmed_only)
