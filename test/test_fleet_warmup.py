"""The fleet's warm-up replay (core/fleet/warmup.py): every robot's warm-up filtered again on a
new map once every robot's learned noise is in use."""
import numpy as np

from online_em_slam.core import FleetSlam, OnlineEMSlam
from online_em_slam.core.config import NoiseLearningConfig, replace_section
from online_em_slam.core.em.noise.learner import NoiseLearner
from online_em_slam.experiments.simulation import ScenarioConfig, feed, fleet_scenarios, simulate, slam_config_for
from test_fleet import _Robot, _run_fleet
from test_noise_learning import PARTICLES, TRUTH, started_wrong


def _learning(scenario, **learning):
    return started_wrong(slam_config_for(scenario, num_particles=PARTICLES, seed=1), 3.0, **learning)


def test_a_one_robot_fleet_replays_its_warmup_as_the_single_robot_does():
    """The fleet's replay (new map, robot restarted, held learned values, the kept inputs again)
    is the single robot's replay (filter/warmup.py), bit for bit, with one robot."""
    scenario = simulate(ScenarioConfig(seed=2, n_steps=600, outlier_probability=0.1, **TRUTH))
    config = _learning(scenario)
    single = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(single, step)
    fleet = _run_fleet([scenario], config)
    assert single.learned_noise()["warmup_replayed"] and fleet.robot(0).learned_noise()["warmup_replayed"]
    assert fleet._warmup_log is None and fleet.drops == single.drops
    assert single.learned_noise()["replays"] == fleet.robot(0).learned_noise()["replays"] == 1
    a, b = single.landmarks(), fleet.landmarks()
    for name in ("ids", "positions", "covariances", "n_obs", "confirmed"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(single.particles()[0], fleet.particles(0)[0])
    assert single.learned_noise() == fleet.robot(0).learned_noise()
    assert np.array_equal(single.revised_trajectory(), fleet.revised_trajectory(0))     # the replay's poses


def test_a_one_robot_fleet_replays_as_its_inputs_grow_as_the_single_robot_does():
    """With replay_growth the fleet filters its kept inputs again each time they have grown
    g-fold, as a single robot does (filter/warmup.py): the same replays, the same map."""
    scenario = simulate(ScenarioConfig(seed=2, n_steps=1200, outlier_probability=0.1, **TRUTH))
    config = _learning(scenario, replay_growth=1.25)
    single = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(single, step)
    fleet = _run_fleet([scenario], config)
    assert single.learned_noise()["replays"] == fleet.robot(0).learned_noise()["replays"] >= 2
    assert fleet._warmup_log is not None and len(fleet._warmup_log) == len(single._warmup.inputs)
    assert fleet.drops == single.drops
    a, b = single.landmarks(), fleet.landmarks()
    for name in ("ids", "positions", "covariances", "n_obs", "confirmed"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert single.learned_noise() == fleet.robot(0).learned_noise()


def test_two_robots_replay_again_as_their_inputs_grow():
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=800, seed=0, outlier_probability=0.1, **TRUTH), 2)
    grown = _run_fleet(scenarios, _learning(scenarios[0], replay_growth=1.25))
    counts = [grown.robot(r).learned_noise()["replays"] for r in range(2)]
    assert counts[0] == counts[1] >= 2
    assert grown._warmup_log is not None and grown._warmup.replaying is None
    for r, scenario in enumerate(scenarios):          # each robot's poses from its first scan on
        revised = grown.revised_trajectory(r)
        assert revised[0, 0] == scenario.steps[0].stamp and np.all(np.diff(revised[:, 0]) > 0)


def test_the_fleet_replays_once_every_robot_has_its_learned_values_in_use(monkeypatch):
    """Two robots: nothing is replayed while one robot still runs on configured values; then
    once, every robot held at its learned values through the replay; drops counted once."""
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=600, seed=0, outlier_probability=0.1, **TRUTH), 2)
    replays = []
    replay = FleetSlam.restart_map

    def recording(self, poses, from_start=False):
        replays.append([self.robot(r)._noise.all_in_use for r in range(self.n_robots)] if from_start else None)
        replay(self, poses, from_start)
    monkeypatch.setattr(FleetSlam, "restart_map", recording)
    held = []
    update = NoiseLearner.update

    def noting(self, *args, **kwargs):
        update(self, *args, **kwargs)
        held.append(self.holding)
    monkeypatch.setattr(NoiseLearner, "update", noting)

    fleet = _run_fleet(scenarios, _learning(scenarios[0]))
    plain = _run_fleet(scenarios, _learning(scenarios[0], replay_warmup=False))
    assert replays == [[True, True]]
    assert all(fleet.robot(r).learned_noise()["warmup_replayed"] for r in range(2))
    assert any(held) and not held[-1]
    assert fleet.drops == plain.drops


def test_a_robot_put_elsewhere_ends_the_fleets_replay():
    """A pose set from outside (an initial-pose message, a relocalisation) means the kept inputs
    no longer lead to the fleet's state: no replay, as for a single robot."""
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=600, seed=0, outlier_probability=0.1, **TRUTH), 2)
    fleet = FleetSlam(_learning(scenarios[0]), [s.initial_pose for s in scenarios], stamp=0.0)
    fleet.set_pose(1, scenarios[1].initial_pose)
    assert fleet._warmup_log is None
    for k in range(600):
        for robot, scenario in enumerate(scenarios):
            feed(_Robot(fleet, robot), scenario.steps[k])
    assert not any(fleet.robot(r).learned_noise()["warmup_replayed"] for r in range(2))



def test_after_the_fleets_replay_a_bad_motion_input_is_still_counted():
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=600, seed=0, outlier_probability=0.1, **TRUTH), 2)
    fleet = _run_fleet(scenarios, _learning(scenarios[0]))
    assert fleet.robot(1).learned_noise()["warmup_replayed"]
    before = fleet.drops["non_finite_control"]
    fleet.add_control(1, scenarios[1].steps[-1].stamp + 0.1, np.array([np.nan, 0.0]))
    assert fleet.drops["non_finite_control"] == before + 1


def test_a_one_robot_fleet_started_at_the_learned_values_does_not_replay_as_the_single_robot():
    """Started at its truth (Gaussian noise), the single robot finds its warm-up replay needless
    (core/em/noise/start_difference.py); a one-robot fleet decides the same, bit for bit."""
    scenario = simulate(ScenarioConfig(seed=1, n_steps=800))
    config = replace_section(slam_config_for(scenario, num_particles=30, seed=0),
                             noise_learning=NoiseLearningConfig(enabled=True))
    single = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        feed(single, step)
    fleet = _run_fleet([scenario], config)
    for learned in (single.learned_noise(), fleet.robot(0).learned_noise()):
        assert learned["warmup_replay_needless"] and not learned["warmup_replayed"]
    assert fleet._warmup_log is None and single.learned_noise() == fleet.robot(0).learned_noise()
    a, b = single.landmarks(), fleet.landmarks()
    for name in ("ids", "positions", "covariances", "n_obs"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
