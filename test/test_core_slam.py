"""The online EM estimator end to end on the seed's simulated experiment."""
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from online_em_slam.core import Observations, OnlineEMSlam, SlamConfig
from online_em_slam.offline.evaluation import map_error_split
from online_em_slam.experiments.simulation import ScenarioConfig, feed, landmark_rmse, simulate, slam_config_for


def dead_reckoning_map_rmse(scenario):
    """Landmark error of mapping with odometry alone (first sighting, no correction): the 'no SLAM' level."""
    config = slam_config_for(scenario)
    from online_em_slam.core.models.motion import propagate
    pose = scenario.initial_pose[None]
    first = {}
    for step in scenario.steps:
        pose, _, _ = propagate(config.motion, pose, step.control, scenario.config.dt)
        for r, b, i in zip(step.ranges, step.bearings, step.true_ids):
            first.setdefault(int(i), pose[0, :2] + r * np.array([np.cos(pose[0, 2] + b), np.sin(pose[0, 2] + b)]))
    ids = np.array(sorted(first))
    return landmark_rmse(ids, np.array([first[i] for i in ids]), scenario.landmarks)


def run(scenario, **sections):
    config = slam_config_for(scenario)
    for section, values in sections.items():
        for key, value in values.items():
            setattr(getattr(config, section), key, value)
    slam = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps:
        report = feed(slam, step)
        assert np.all(np.isfinite(slam.pose().mean))
    return slam, report


@pytest.fixture(scope="module")
def known_scenario():
    return simulate(ScenarioConfig(seed=0, n_steps=1500))


def test_known_association_map_converges(known_scenario):
    """Seed 0, 1500 steps, N = 100, the default observed-information M-step.
    The GTSAM batch optimum on this seed: RMSE 1.64 m, shape 0.26 m; measured
    here 1.84 m and 0.23 m (dead reckoning: 4.8 m).  We ask for the shape (what
    the M-step controls) at 0.35 m, the total within 1.5x of the batch optimum
    and half the dead-reckoning map error."""
    slam, _ = run(known_scenario)
    lm = slam.landmarks()
    assert len(lm) == 20 and np.all(lm.confirmed)
    rmse = landmark_rmse(lm.ids, lm.positions, known_scenario.landmarks)
    _, shape, _ = map_error_split(lm.positions, known_scenario.landmarks[lm.ids])
    assert shape < 0.35
    assert rmse < 1.5 * 1.64
    assert rmse < dead_reckoning_map_rmse(known_scenario) / 2
    assert np.all(np.isfinite(lm.covariances)) and np.all(np.linalg.eigvalsh(lm.covariances) > 0)


def test_complete_data_m_step_still_maps_but_keeps_a_deformed_map(known_scenario):
    """The seed's M-step stays selectable; its shape error is the one the observed
    information removes (measured on seed 0: 0.9 m against 0.23 m)."""
    complete, _ = run(known_scenario, em={"m_step": "complete"})
    lm = complete.landmarks()
    assert len(lm) == 20
    _, shape, _ = map_error_split(lm.positions, known_scenario.landmarks[lm.ids])
    assert 0.35 < shape < 2.0


def test_unknown_association_finds_every_landmark_once():
    scenario = simulate(ScenarioConfig(seed=0, n_steps=1500, known_ids=False))
    slam, _ = run(scenario)
    lm = slam.landmarks(confirmed_only=True)
    assert len(lm) == 20, "every landmark found, no duplicates"
    distances = np.linalg.norm(lm.positions[:, None] - scenario.landmarks[None], axis=-1)
    rows, cols = linear_sum_assignment(distances)
    # The batch optimum of this seed (known ids) is 1.64 m; measured 1.84 m.
    assert np.sqrt(np.mean(distances[rows, cols] ** 2)) < 1.5 * 1.64
    assert distances[rows, cols].max() < 4.0


@pytest.mark.parametrize("smoother", ["paris", "ancestry"])
@pytest.mark.parametrize("algorithm", ["online", "block_averaged"])
def test_every_smoother_and_em_variant_maps_a_short_run(smoother, algorithm):
    scenario = simulate(ScenarioConfig(seed=1, n_steps=300))
    slam, _ = run(scenario, filter={"smoother": smoother}, em={"algorithm": algorithm, "block_initial_length": 10})
    lm = slam.landmarks()
    assert landmark_rmse(lm.ids, lm.positions, scenario.landmarks) < dead_reckoning_map_rmse(scenario)


def test_outliers_with_mixture_noise_do_not_break_the_map():
    scenario = simulate(ScenarioConfig(seed=0, n_steps=600, outlier_probability=0.1))
    slam, _ = run(scenario)      # slam_config_for picks the mixture noise
    assert slam.config.noise.model == "mixture"
    lm = slam.landmarks()
    assert np.all(np.isfinite(lm.positions))
    assert landmark_rmse(lm.ids, lm.positions, scenario.landmarks) < dead_reckoning_map_rmse(scenario)


def test_seeded_runs_are_deterministic():
    scenario = simulate(ScenarioConfig(seed=2, n_steps=100))
    a, _ = run(scenario)
    b, _ = run(scenario)
    np.testing.assert_array_equal(a.landmarks().positions, b.landmarks().positions)
    np.testing.assert_array_equal(a.pose().mean, b.pose().mean)


def test_memory_does_not_grow_with_time():
    """Once every landmark is mapped (after the first lap), the state size is constant."""
    scenario = simulate(ScenarioConfig(seed=0, n_steps=1000))
    slam = OnlineEMSlam(slam_config_for(scenario), initial_pose=scenario.initial_pose, stamp=0.0)
    sizes = []
    for k, step in enumerate(scenario.steps):
        feed(slam, step)
        if k in (700, 999):
            sizes.append(sum(v.nbytes for v in vars(slam).values() if isinstance(v, np.ndarray)))
    assert sizes[0] == sizes[1]


def test_bad_inputs_are_dropped_and_counted_not_raised():
    slam = OnlineEMSlam(SlamConfig(), stamp=0.0)
    slam.add_control(0.0, (1.0, 0.0))
    assert not slam.add_control(0.1, (np.nan, 0.0))
    report = slam.add_observations(1.0, Observations([np.nan, -1.0, 5.0, 1e6, np.inf], [0.0, 0.0, np.nan, 0.0, 0.1]))
    assert report.dropped["invalid_observation"] == 4 and report.dropped["observation_out_of_range"] == 1
    report = slam.add_observations(0.5, Observations([5.0], [0.0]))
    assert slam.drops["out_of_order"] == 1
    slam.add_control(1e5, (1.0, 0.1))            # a huge time step is clipped, not integrated
    assert slam.drops["large_time_step_clipped"] >= 1
    # An observation on top of the robot and an empty scan.
    slam.add_observations(1e5 + 1, Observations([0.0, 3.0], [0.0, 0.0], [7, 7]))
    slam.add_observations(1e5 + 2, Observations([], []))
    assert slam.drops["duplicate_id"] == 1
    assert np.all(np.isfinite(slam.pose().mean)) and np.all(np.isfinite(slam.pose().covariance))
    lm = slam.landmarks()
    assert np.all(np.isfinite(lm.positions)) and np.all(np.isfinite(lm.covariances))


def test_degenerate_weights_recover_without_nan():
    """Every particle explains an observation with likelihood ~0: weights fall back, no NaN."""
    config = SlamConfig()
    config.association.min_observations_for_weighting = 1
    slam = OnlineEMSlam(config, stamp=0.0)
    slam.add_observations(0.1, Observations([10.0], [0.0], [0]))
    slam.add_observations(0.2, Observations([10.0], [0.0], [0]))
    slam.add_observations(0.3, Observations([1e3 - 1], [3.1], [0]))
    poses, weights = slam.particles()
    assert np.all(np.isfinite(poses)) and np.isclose(weights.sum(), 1.0)
    assert np.all(np.isfinite(slam.landmarks().positions))


def test_save_and_load_map_continue_estimation(tmp_path, known_scenario):
    scenario = simulate(ScenarioConfig(seed=0, n_steps=200))
    slam, _ = run(scenario)
    path = tmp_path / "map.npz"
    slam.save_map(path)
    before = slam.landmarks()
    slam.reset()
    assert len(slam.landmarks()) == 0
    slam.load_map(path)
    after = slam.landmarks()
    np.testing.assert_array_equal(before.positions, after.positions)
    np.testing.assert_array_equal(before.ids, after.ids)
    np.testing.assert_allclose(before.covariances, after.covariances)
    report = slam.add_observations(slam.last_stamp + 0.2 if slam.last_stamp else 0.2,
                                   scenario.steps[10].observations())
    assert report.n_created == 0 and report.n_associated > 0


def test_a_new_pass_starts_from_the_map_with_fresh_statistics():
    """Batch EM by repeated passes: the map is kept as the starting point, the
    statistics and step-size counts restart, the second pass maps the same landmarks."""
    scenario = simulate(ScenarioConfig(seed=0, n_steps=300))
    slam, _ = run(scenario, em={"m_step": "complete"})
    first = slam.landmarks()
    slam.start_new_pass(scenario.initial_pose, stamp=0.0)
    restarted = slam.landmarks()
    np.testing.assert_array_equal(restarted.positions, first.positions)
    np.testing.assert_array_equal(restarted.ids, first.ids)
    assert slam.step_count == 0 and not slam._m_step.count.any()
    for step in scenario.steps:
        feed(slam, step)
    second = slam.landmarks()
    np.testing.assert_array_equal(np.sort(second.ids), np.sort(first.ids))
    assert np.all(np.isfinite(second.positions))
    # A pass is one EM iteration: it may not move the map far from where it started.
    assert (landmark_rmse(second.ids, second.positions, scenario.landmarks)
            < landmark_rmse(first.ids, first.positions, scenario.landmarks) + 0.5)


@pytest.mark.parametrize("spread", ["relocalised", "at_the_saved_pose"])
def test_a_map_reloaded_after_the_robot_moved_is_found_again(tmp_path, spread):
    """Reliability issue, item 4: save the map, drive on 7.8 m and turn 0.66 rad, restart from
    the file (the saved pose is stale). Relocalised (the default), the particles spread
    around the saved pose and the known landmarks weigh them before any landmark is created:
    the pose ends within 2 m of the run that never stopped (measured 1.57 m; 0.50 and 0.80 m
    after 3.6 and 5.8 m). Kept at the saved pose (relocalisation_std 0), the robot is lost
    (21 m off). Beyond the spread (10.8 m and 1 rad) both are lost."""
    import copy
    from dataclasses import replace

    scenario = simulate(ScenarioConfig(seed=0, n_steps=1500, known_ids=False))
    config = slam_config_for(scenario)
    if spread == "at_the_saved_pose":
        config = replace(config, filter=replace(config.filter, relocalisation_std=(0.0, 0.0, 0.0)))
    first = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    for step in scenario.steps[:700]:
        feed(first, step)
    first.save_map(tmp_path / "map.npz")
    uninterrupted = copy.deepcopy(first)
    for step in scenario.steps[700:800]:
        feed(uninterrupted, step)
    second = OnlineEMSlam(config, initial_pose=scenario.initial_pose, stamp=0.0)
    second.load_map(tmp_path / "map.npz")
    assert second.relocalising
    for step in scenario.steps[714:800]:                     # 14 steps driven before the restart
        feed(second, step)
    off = np.linalg.norm(second.pose().mean[:2] - uninterrupted.pose().mean[:2])
    extra = len(second.landmarks(confirmed_only=True)) - len(uninterrupted.landmarks(confirmed_only=True))
    if spread == "relocalised":
        assert off < 2.0 and extra <= 1 and not second.relocalising, (off, extra)
    else:
        assert off > 10.0, off


@pytest.mark.parametrize("known", [True, False])
def test_only_a_landmark_made_without_an_id_is_pruned_while_tentative(known):
    """A landmark seen once and then out of view for longer than the timeout: with the id the
    sensor read it waits to be seen again (as the baselines' LandmarkBook); without, it goes."""
    config = SlamConfig()
    config.association.tentative_timeout = 3
    slam = OnlineEMSlam(config, stamp=0.0)
    slam.add_observations(0.1, Observations([4.0], [0.3], [5] if known else None))
    for k in range(8):
        slam.add_observations(0.2 + 0.1 * k, Observations([], []))
    assert len(slam.landmarks()) == (1 if known else 0)
    if known:
        for k in range(2):
            slam.add_observations(1.1 + 0.1 * k, Observations([4.0], [0.3], [5]))
        assert slam.landmarks(confirmed_only=True).ids.tolist() == [5]
