"""The trajectory as a replay filtered it again (filter/warmup.py, ``revised_trajectory``): the
poses the replaying estimator had after each scan, checked against a second estimator fed the
same inputs from the same start by hand; the node's path takes them over (ros/path_history.py)."""
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.filter.warmup import WarmupReplay
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for


def _config(scenario, growth=0.0):
    """Observation noise started at 3x its truth, so the warm-up replay is due (start_difference.py)."""
    config = slam_config_for(scenario, num_particles=30, seed=0)
    noise = replace(config.noise, sigma_range=3.0 * config.noise.sigma_range,
                    sigma_bearing=3.0 * config.noise.sigma_bearing)
    return replace_section(config, noise=noise, noise_learning=NoiseLearningConfig(
        enabled=True, learn=("range", "bearing"), warmup_observations=100, replay_growth=growth))


@pytest.fixture(scope="module")
def scenario():
    return simulate(ScenarioConfig(seed=3, n_steps=300))


def _run(scenario, config, on_replay=None):
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    replays = 0
    for step in scenario.steps:
        slam.add_control(step.control_stamp, step.control)
        slam.add_observations(step.stamp, step.observations())
        if on_replay is not None and slam.learned_noise()["replays"] > replays:
            replays = slam.learned_noise()["replays"]
            on_replay(slam, step)
    return slam


def test_no_replay_no_revised_trajectory(scenario):
    config = replace_section(_config(scenario), noise_learning=NoiseLearningConfig(enabled=False))
    assert _run(scenario, config).revised_trajectory() is None


def test_the_revised_poses_are_those_of_the_inputs_filtered_again(scenario, monkeypatch):
    """Each row is the replaying estimator's pose after a scan: the same as a copy of the restarted
    estimator, fed the kept inputs one by one, gives."""
    by_hand = []
    restarted = WarmupReplay._restarted

    def twin(self, estimator):
        fresh = restarted(self, estimator)
        copy = restarted(self, estimator)
        for method, stamp, value in self.inputs:
            getattr(copy, method)(stamp, value)
            if method == "add_observations":
                by_hand.append((stamp, *copy.pose().mean))
        return fresh
    monkeypatch.setattr(WarmupReplay, "_restarted", twin)
    at_take_over = []
    slam = _run(scenario, _config(scenario), lambda s, step: at_take_over.append((step.stamp, *s.pose().mean)))
    rows = slam.revised_trajectory()
    assert len(at_take_over) == 1 and rows.shape == (len(by_hand), 4)
    assert np.array_equal(rows, np.asarray(by_hand))
    assert np.all(np.diff(rows[:, 0]) > 0) and rows[-1, 0] == at_take_over[0][0]
    assert np.array_equal(rows[-1], at_take_over[0])       # the replayed estimator took over


def test_each_replay_revises_the_whole_past(scenario):
    """With growth, the last replay's poses run from the first scan to its take-over."""
    last = []
    slam = _run(scenario, _config(scenario, growth=1.5), lambda s, step: last.append(step.stamp))
    rows = slam.revised_trajectory()
    assert len(last) >= 2 and rows[-1, 0] == last[-1]
    assert rows[0, 0] == scenario.steps[0].stamp


def test_the_path_takes_the_revised_poses_and_keeps_the_later_ones():
    from std_msgs.msg import Header
    from online_em_slam.ros.path_history import PathHistory
    path = PathHistory(maxlen=100, max_poses=1000)
    for k in range(60):
        path.append(float(k), (k, 0.0, 0.0))
    revised = np.column_stack([np.arange(0.5, 40.0, 1.0), np.full(40, -1.0), np.zeros(40), np.zeros(40)])
    revised[3, 1] = np.nan                                 # a pose that is not finite is left out
    path.revise(revised)
    rows = path._ordered()
    assert len(path) == 39 + 20 and np.all(np.diff(rows[:, 0]) > 0)
    assert np.all(rows[:39, 1] == -1.0) and np.array_equal(rows[39:, 1], np.arange(40.0, 60.0))
    msg = path.to_msg(Header(frame_id="map"))
    assert len(msg.poses) == 59 and msg.poses[0].pose.position.x == -1.0
    path.append(60.0, (60.0, 0.0, 0.0))                    # the path goes on after it
    assert len(path) == 60 and path.to_msg(Header()).poses[-1].pose.position.x == 60.0
    small = PathHistory(maxlen=10)
    small.revise(revised)
    assert len(small) == 10 and small._ordered()[-1, 0] == 39.5       # the newest maxlen


def test_the_node_revises_its_path_once_per_replay():
    from types import SimpleNamespace
    from online_em_slam.ros.outputs import Outputs
    replays = []
    slam = SimpleNamespace(revised_trajectory=lambda: replays[-1] if replays else None)
    node = SimpleNamespace(settings=SimpleNamespace(path_max_length=100, path_publish_max_poses=50), slam=slam)
    outputs = Outputs(node, diagnostics=None, robot_outputs=False, map_outputs=False)
    for k in range(10):
        outputs.path.append(float(k), (k, 0.0, 0.0))
    outputs._revise_path()
    assert len(outputs.path) == 10                              # no replay yet
    replays.append(np.array([[0.0, -1.0, 0.0, 0.0], [5.0, -5.0, 0.0, 0.0]]))
    outputs._revise_path()
    assert len(outputs.path) == 2 + 4 and outputs.path._ordered()[1, 1] == -5.0
    outputs.path.append(10.0, (10.0, 0.0, 0.0))
    outputs._revise_path()                                      # the same replay: the path goes on
    assert len(outputs.path) == 7
