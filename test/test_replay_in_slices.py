"""The warm-up replay in slices (filter/warmup.py, a live node's way): the estimator goes on
under the first pass while the replay catches up a few inputs at a time, and once it has
taken over the result is the replay made at once, bit for bit."""
import numpy as np

from online_em_slam.core import FleetSlam, OnlineEMSlam
from online_em_slam.experiments.simulation import ScenarioConfig, feed, fleet_scenarios, simulate
from test_fleet import _Robot
from test_fleet_warmup import _learning
from test_noise_learning import TRUTH


def _same_map(a, b) -> None:
    for name in ("ids", "positions", "covariances", "n_obs", "confirmed"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_a_replay_in_slices_ends_where_the_replay_at_once_does():
    scenario = simulate(ScenarioConfig(seed=2, n_steps=700, outlier_probability=0.1, **TRUTH))
    config = _learning(scenario)
    at_once = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    sliced = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    sliced.replay_in_slices = True
    catching_up = []
    for step in scenario.steps:
        feed(at_once, step)
        feed(sliced, step)
        catching_up.append(sliced.advance_replay(16))
    assert any(catching_up) and not catching_up[-1]          # it caught up before the end
    assert sliced.learned_noise()["warmup_replayed"] and sliced._warmup_log is None
    _same_map(at_once.landmarks(), sliced.landmarks())
    assert np.array_equal(at_once.particles()[0], sliced.particles()[0])
    assert at_once.learned_noise() == sliced.learned_noise()
    assert at_once.drops == sliced.drops


def test_a_fleet_replay_in_slices_ends_where_the_replay_at_once_does():
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=700, seed=0, outlier_probability=0.1, **TRUTH), 2)
    config = _learning(scenarios[0])
    fleets = [FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0) for _ in range(2)]
    fleets[1].replay_in_slices = True
    catching_up = []
    for k in range(700):
        for fleet in fleets:
            for robot, scenario in enumerate(scenarios):
                feed(_Robot(fleet, robot), scenario.steps[k])
        catching_up.append(fleets[1].advance_replay(16))
    assert any(catching_up) and not catching_up[-1]
    _same_map(fleets[0].landmarks(), fleets[1].landmarks())
    for r in range(2):
        assert np.array_equal(fleets[0].particles(r)[0], fleets[1].particles(r)[0])
        assert fleets[1].robot(r).learned_noise()["warmup_replayed"]


def test_a_fleets_replays_as_its_inputs_grow_in_slices_end_where_those_at_once_do():
    scenario = simulate(ScenarioConfig(seed=2, n_steps=1200, outlier_probability=0.1, **TRUTH))
    config = _learning(scenario, replay_growth=1.25)
    fleets = [FleetSlam(config, [scenario.initial_pose], stamp=0.0) for _ in range(2)]
    fleets[1].replay_in_slices = True
    for step in scenario.steps:
        for fleet in fleets:
            feed(_Robot(fleet, 0), step)
        fleets[1].advance_replay(64)
    while fleets[1].advance_replay(64):
        pass
    assert fleets[0].robot(0).learned_noise()["replays"] == fleets[1].robot(0).learned_noise()["replays"] >= 2
    _same_map(fleets[0].landmarks(), fleets[1].landmarks())
    assert np.array_equal(fleets[0].particles(0)[0], fleets[1].particles(0)[0])


def test_a_pose_set_while_the_replay_catches_up_ends_it():
    scenario = simulate(ScenarioConfig(seed=2, n_steps=700, outlier_probability=0.1, **TRUTH))
    sliced = OnlineEMSlam(_learning(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
    sliced.replay_in_slices = True
    for step in scenario.steps:
        feed(sliced, step)
        if sliced.advance_replay(1):
            sliced.set_pose(sliced.pose().mean)
            break
    assert sliced._warmup.replaying is None and sliced._warmup_log is None
    assert not sliced.advance_replay(1) and not sliced.learned_noise()["warmup_replayed"]


def test_the_nodes_timer_feeds_the_replay_and_checkpoints_the_inputs_when_it_takes_over():
    """ros/warmup_replay.py: a tick feeds the replay for at most its budget; the tick that sees
    the replayed estimator take over checkpoints the inputs (a failing input must not undo it)."""
    import threading
    from types import SimpleNamespace

    from online_em_slam.ros import warmup_replay

    scenario = simulate(ScenarioConfig(seed=2, n_steps=700, outlier_probability=0.1, **TRUTH))
    slam = OnlineEMSlam(_learning(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
    slam.replay_in_slices = True
    checkpoints, lines = [], []
    node = SimpleNamespace(lock=threading.RLock(), slam=slam,
                           inputs=SimpleNamespace(pipeline=SimpleNamespace(
                               checkpoint=lambda: checkpoints.append(slam.step_count))),
                           get_logger=lambda: SimpleNamespace(info=lines.append))
    feeder = warmup_replay.WarmupReplayFeeder(node)
    ticks = 0
    for step in scenario.steps:
        feed(slam, step)
        feeder.tick()
        ticks += feeder.catching_up
    assert ticks > 0 and not feeder.catching_up
    assert len(checkpoints) == 1 and len(lines) == 2 and slam.learned_noise()["warmup_replayed"]


def test_the_node_checkpoints_through_an_interface_both_kinds_of_inputs_have():
    """The timer calls ``node.inputs.pipeline.checkpoint()``: the single robot's InputPipeline and
    the fleet's FleetPipelines both have it (the fleet node died on a method only one had)."""
    from online_em_slam.pipeline.input_pipeline import InputPipeline
    from online_em_slam.ros.fleet_inputs import FleetPipelines

    assert callable(InputPipeline.checkpoint) and callable(FleetPipelines.checkpoint)


def test_a_replay_that_fails_is_dropped_and_counted_and_the_first_pass_goes_on(monkeypatch):
    from online_em_slam.core.filter.warmup import WarmupReplay

    scenario = simulate(ScenarioConfig(seed=2, n_steps=700, outlier_probability=0.1, **TRUTH))
    fed = []

    def failing(estimator, method, stamp, value):
        fed.append(method)
        if len(fed) == 50:
            raise FloatingPointError("a failure inside the replay")
        getattr(estimator, method)(stamp, value)
    monkeypatch.setattr(WarmupReplay, "_feed", staticmethod(failing))
    for in_slices in (False, True):
        fed.clear()
        slam = OnlineEMSlam(_learning(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
        slam.replay_in_slices = in_slices
        for step in scenario.steps:
            feed(slam, step)
            slam.advance_replay(16)
        assert slam.drops["warmup_replay_failed"] == 1 and len(fed) == 50
        assert not slam.learned_noise()["warmup_replayed"] and slam._warmup_log is None
        assert np.all(np.isfinite(slam.landmarks().positions)) and slam.step_count > 600


def test_a_replay_that_fails_to_start_is_dropped_and_counted_and_the_first_pass_goes_on(monkeypatch):
    """The restart raised out of the input that made the replay due; the rollback undid that input,
    the replay was due again at the next one, and every later scan failed the same way."""
    from online_em_slam.core.filter.warmup import WarmupReplay

    scenario = simulate(ScenarioConfig(seed=2, n_steps=700, outlier_probability=0.1, **TRUTH))
    attempts = []

    def failing(self, estimator):
        attempts.append(estimator.step_count)
        raise TypeError("a failure restarting the estimator")
    monkeypatch.setattr(WarmupReplay, "_restarted", failing)
    slam = OnlineEMSlam(_learning(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(slam, step)
    assert len(attempts) == 1 and slam.drops["warmup_replay_failed"] == 1
    assert not slam.learned_noise()["warmup_replayed"] and slam._warmup_log is None
    assert np.all(np.isfinite(slam.landmarks().positions)) and slam.step_count > 600
