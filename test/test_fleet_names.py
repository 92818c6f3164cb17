"""Fleet mode's per-robot names and its parameters (no ROS graph needed)."""
import numpy as np
import pytest

from online_em_slam.parameters.specs import ParameterError, build
from online_em_slam.ros.fleet_names import RobotNames, fleet_names, initial_poses, prefixed


def test_topics_and_frames_are_prefixed_with_the_robot():
    _, settings = build({"robots": ["robot1", "team/robot2"], "sensor_frame": "laser"})
    names = fleet_names(settings)
    assert [n.robot for n in names] == ["robot1", "team/robot2"]
    robot = names[0].settings(settings)
    assert (robot.odom_topic, robot.control_topic, robot.observations_topic) == (
        "robot1/odom", "robot1/control", "robot1/landmark_observations")
    assert (robot.odom_frame, robot.base_frame, robot.sensor_frame) == ("robot1/odom", "robot1/base_link",
                                                                        "robot1/laser")
    assert robot.map_frame == "map"                                  # one map for the fleet
    assert names[1].topic("~/pose") == "team/robot2/pose"            # the single node's outputs, per robot
    assert names[1].topic("~/particles") == "team/robot2/particles"
    assert RobotNames("r").topic("/tf") == "/tf" and prefixed("r", "/diagnostics") == "/diagnostics"
    assert names[0].settings(build({"robots": ["robot1"]})[1]).sensor_frame == ""   # empty: any frame


def test_initial_poses_per_robot_or_initial_pose():
    _, settings = build({"robots": ["a", "b"], "initial_poses": [1, 2, 0.5, -3.0, 4.0, -1.0]})
    assert np.allclose(initial_poses(settings), [[1, 2, 0.5], [-3, 4, -1]])
    _, settings = build({"robots": ["a", "b"], "initial_pose.x": 5.0})
    assert np.allclose(initial_poses(settings), [[5, 0, 0], [5, 0, 0]])


def test_single_robot_by_default():
    _, settings = build({})
    assert settings.robots == () and settings.initial_poses == ()


@pytest.mark.parametrize("values, message", [
    ({"robots": ["a", "a"]}, "appears twice"),
    ({"robots": ["/abs"]}, "not a relative ROS name"),
    ({"robots": ["1robot"]}, "not a relative ROS name"),
    ({"robots": ["a", "b"], "initial_poses": [0.0, 0.0, 0.0]}, "3 numbers"),
    ({"robots": ["a"], "initial_poses": [0.0, 0.0, 4.0]}, "initial_poses[2]"),
    ({"robots": ["a"], "initial_poses": ["x", "y", "z"]}, "expected numbers"),
    ({"robots": ["a"], "em.m_step": "complete"}, "em.m_step must be observed"),
])
def test_fleet_parameters_are_checked(values, message):
    with pytest.raises(ParameterError, match=message.replace("[", r"\[").replace("]", r"\]")):
        build(values)


def test_diagnostics_carry_each_robots_ess_stamp_and_learned_noise():
    from online_em_slam.core import Observations
    from online_em_slam.core.config import SlamConfig
    from online_em_slam.ros.fleet_estimate import FleetEstimate
    from dataclasses import replace
    config = SlamConfig()
    config = replace(config, noise_learning=replace(config.noise_learning, enabled=True))
    estimate = FleetEstimate(config, np.zeros((2, 3)), ("robot1", "robot2"))
    estimate.fleet.add_observations(1, 0.5, Observations(np.array([5.0]), np.array([0.1]), np.array([3])))
    values = estimate.robot_diagnostics()
    assert values["robot1.last_stamp"] == -1.0 and values["robot2.last_stamp"] == 0.5
    assert values["robot1.ess"] == values["robot2.ess"] == SlamConfig().filter.num_particles
    assert "robot2.noise_learned.sigma_range" in values
