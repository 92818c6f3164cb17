"""Fleet robots as pipeline estimators (pipeline/fleet.py, the views the node feeds): one robot's failing input
puts the whole fleet back, so the shared map is as if that input had never come."""
import numpy as np

from online_em_slam.core.fleet.slam import FleetSlam
from online_em_slam.experiments.simulation import ScenarioConfig, fleet_scenarios, slam_config_for
from online_em_slam.pipeline.feeder import Feeder
from online_em_slam.pipeline.fleet import robot_views
from online_em_slam.pipeline.inputs import CONTROL, OBSERVATIONS, Input


def _run(fail_at=None):
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=40, seed=0), 2)
    fleet = FleetSlam(slam_config_for(scenarios[0], num_particles=20, seed=0), [s.initial_pose for s in scenarios],
                      0.0)
    feeds = robot_views(fleet)
    feeders = [Feeder(feed, "control") for feed in feeds]
    for k in range(40):
        for r, scenario in enumerate(scenarios):
            step = scenario.steps[k]
            feeders[r].apply(Input(step.control_stamp, CONTROL, payload=step.control))
            if (r, k) == fail_at:          # a scan whose processing raises half-way
                robot = fleet.robot(r)
                original = robot.add_observations

                def broken(stamp, obs, original=original):
                    original(stamp, obs)
                    raise RuntimeError("boom")
                robot.add_observations = broken
                fed = feeders[r].apply(Input(step.stamp, OBSERVATIONS, payload=step.observations()))
                assert fed.error is not None and feeders[r].drops["internal_error"] == 1
                assert "add_observations" not in fleet.robot(r).__dict__   # the checkpoint put back
                continue
            feeders[r].apply(Input(step.stamp, OBSERVATIONS, payload=step.observations()))
    return fleet


def _skip_run(skip):
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=40, seed=0), 2)
    fleet = FleetSlam(slam_config_for(scenarios[0], num_particles=20, seed=0), [s.initial_pose for s in scenarios],
                      0.0)
    for k in range(40):
        for r, scenario in enumerate(scenarios):
            step = scenario.steps[k]
            fleet.add_control(r, step.control_stamp, step.control)
            if (r, k) != skip:
                fleet.add_observations(r, step.stamp, step.observations())
    return fleet


def test_a_failing_input_of_one_robot_leaves_no_trace_in_the_fleet():
    failed, skipped = _run(fail_at=(1, 25)), _skip_run(skip=(1, 25))
    a, b = failed.landmarks(), skipped.landmarks()
    assert np.array_equal(a.ids, b.ids) and np.allclose(a.positions, b.positions)
    for r in range(2):
        assert np.allclose(failed.pose(r).mean, skipped.pose(r).mean)
