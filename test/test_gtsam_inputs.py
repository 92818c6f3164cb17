"""The GTSAM batch reference on recorded inputs (offline/batch.py).

(a) On a simulated run fed as events it is :func:`batch_estimate`'s problem, to 1e-6.
(b) With the odometry model, noise-free odometry and scans give back the truth, and
    the compounded motion covariance between two scans equals the estimator's own
    vectorised integration (motion.integrate_segments): an independent check.
(c) With a control model at irregular stamps (several controls per scan, clipped
    steps) the between factors are the estimator's transitions, read off OnlineEMSlam.
(d) The sensor lever arm: the custom factor's Jacobians, and truth recovered.
(e) The incremental (iSAM2) starting point reaches the same optimum.
(f) The estimator's model: the travel rule's scans, and a Student-t observation costing its
    negative log-likelihood.
"""
from dataclasses import replace

import numpy as np
import pytest

from online_em_slam.offline.batch import collect_problem
from online_em_slam.offline.observation_factors import lever_arm_measurement
from online_em_slam.core import OnlineEMSlam
from online_em_slam.core.config import MotionConfig, SlamConfig
from online_em_slam.core.models.motion import integrate_segments, odometry_increment, step_jitter
from online_em_slam.core.models.observation import pose_jacobian, predict_observation, sensor_poses
from online_em_slam.core.types import Observations
from online_em_slam.pipeline.inputs import CONTROL, OBSERVATIONS, ODOMETRY
from online_em_slam.experiments.simulation import ScenarioConfig, bicycle_step, simulate, slam_config_for

gtsam = pytest.importorskip("gtsam")
from online_em_slam.baselines.gtsam_batch import batch_estimate  # noqa: E402
from online_em_slam.offline.batch import batch_from_inputs  # noqa: E402


def _rotation(phi: float) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _scenario_events(scenario):
    events = []
    for step in scenario.steps:
        events.append((CONTROL, step.control_stamp, step.control))
        events.append((OBSERVATIONS, step.stamp, Observations(step.ranges, step.bearings, step.true_ids)))
    return events


@pytest.fixture(scope="module")
def scenario():
    return simulate(ScenarioConfig(seed=0, n_steps=200))


def _wide_config(scenario, **sensor):
    """slam_config_for with a range limit batch_estimate does not apply (noisy ranges beyond
    30 m would be dropped by the estimator's rules, which batch_from_inputs follows)."""
    config = slam_config_for(scenario)
    return replace(config, sensor=replace(config.sensor, max_range=1e3, **sensor))


def test_simulated_run_matches_batch_estimate(scenario):
    config = _wide_config(scenario)
    reference = batch_estimate(scenario, config)
    result = batch_from_inputs(_scenario_events(scenario), config, scenario.initial_pose)
    assert result.poses.shape == (len(scenario.steps) + 1, 3)
    np.testing.assert_allclose(result.stamps, scenario.stamps, atol=1e-12)
    np.testing.assert_allclose(result.poses, reference.poses, atol=1e-6)
    seen = np.flatnonzero(np.isfinite(reference.landmarks[:, 0]))
    np.testing.assert_array_equal(result.landmark_ids, seen)
    np.testing.assert_allclose(result.landmarks, reference.landmarks[seen], atol=1e-6)
    assert result.final_error == pytest.approx(reference.final_error, rel=1e-9)
    assert result.final_error < result.initial_error and result.iterations == reference.iterations
    assert result.n_observations == sum(len(s.ranges) for s in scenario.steps) and not result.skipped


def test_incremental_start_reaches_the_same_optimum(scenario):
    config = _wide_config(scenario)
    events = _scenario_events(scenario)
    plain = batch_from_inputs(events, config, scenario.initial_pose)
    incremental = batch_from_inputs(events, config, scenario.initial_pose, init="incremental")
    assert incremental.initial_error < plain.initial_error
    np.testing.assert_allclose(incremental.poses, plain.poses, atol=1e-5)
    np.testing.assert_allclose(incremental.landmarks, plain.landmarks, atol=1e-5)
    assert incremental.final_error == pytest.approx(plain.final_error, rel=1e-8)


def test_lever_arm_factor_equals_bearing_range_factor(scenario):
    """An offset of 1e-12 m takes the custom factor: the same optimum as GTSAM's own factor."""
    events = _scenario_events(scenario)
    plain = batch_from_inputs(events, _wide_config(scenario, offset_yaw=0.05), scenario.initial_pose)
    custom = batch_from_inputs(events, _wide_config(scenario, offset_x=1e-12, offset_yaw=0.05),
                               scenario.initial_pose)
    np.testing.assert_allclose(custom.poses, plain.poses, atol=1e-6)
    np.testing.assert_allclose(custom.landmarks, plain.landmarks, atol=1e-6)
    assert custom.final_error == pytest.approx(plain.final_error, rel=1e-6)


def test_lever_arm_jacobians_are_the_derivatives():
    rng = np.random.default_rng(3)
    offset = (0.7, -0.3, 0.2)
    for _ in range(5):
        pose, landmark = rng.normal(0, 3, 3), rng.normal(0, 10, 2)
        h, H_x, H_l = lever_arm_measurement(pose, landmark, offset)
        sensor = replace(SlamConfig().sensor, offset_x=offset[0], offset_y=offset[1], offset_yaw=offset[2])
        np.testing.assert_allclose(h, predict_observation(sensor_poses(pose, sensor), landmark), atol=1e-12)
        # Pose2 tangent space: X Exp(xi); the world-frame Jacobian rotated into the body frame.
        np.testing.assert_allclose(H_x, pose_jacobian(pose, landmark, sensor) @ _rotation(pose[2]), atol=1e-12)
        eps, X = 1e-6, gtsam.Pose2(*pose)
        for a in range(3):
            xi = np.zeros(3)
            xi[a] = eps
            plus, minus = X.retract(xi), X.retract(-xi)
            d = (lever_arm_measurement((plus.x(), plus.y(), plus.theta()), landmark, offset)[0]
                 - lever_arm_measurement((minus.x(), minus.y(), minus.theta()), landmark, offset)[0])
            np.testing.assert_allclose(d / (2 * eps), H_x[:, a], atol=1e-6)


# --------------------------------------------------------------------------- odometry model

SUB = 4           # odometry messages per scan


def _odometry_run(offset=(0.0, 0.0, 0.0), n_steps=100):
    """A true trajectory at SUB x the scan rate, odometry poses in a rotated and shifted
    odometry frame, noise-free scans (plus an unknown-id and an out-of-range point)."""
    sim = simulate(ScenarioConfig(seed=2, n_steps=n_steps))
    dt = sim.config.dt / SUB
    truth, stamps = [sim.initial_pose], [0.0]
    for control in sim.true_controls:
        for _ in range(SUB):
            truth.append(bicycle_step(truth[-1], control, dt, sim.config.wheelbase))
            stamps.append(stamps[-1] + dt)
    truth, stamps = np.array(truth), np.array(stamps)
    frame = np.array([5.0, -3.0, 0.7])
    c, s = np.cos(frame[2]), np.sin(frame[2])
    odom = np.column_stack([frame[0] + c * truth[:, 0] - s * truth[:, 1],
                            frame[1] + s * truth[:, 0] + c * truth[:, 1], truth[:, 2] + frame[2]])
    motion = MotionConfig(model="odometry", sigma_heading=0.02, odometry_translation_std=0.02,
                          odometry_rotation_std=0.005, odometry_translation_per_meter=0.05)
    config = SlamConfig(motion=motion)
    config = replace(config, sensor=replace(config.sensor, offset_x=offset[0], offset_y=offset[1],
                                            offset_yaw=offset[2], max_range=30.0)).validate()
    events = []
    for i, (t, pose) in enumerate(zip(stamps, odom)):
        events.append((ODOMETRY, t, tuple(pose)))          # odometry before the scan at an equal stamp
        if i % SUB or i == 0:
            continue
        y = predict_observation(sensor_poses(truth[i], config.sensor)[None], sim.landmarks)
        seen = np.flatnonzero(y[:, 0] < 29.0)
        ids = seen.copy()
        ids[:1] = -1                                      # an unknown id: skipped
        ranges = np.append(y[seen, 0], 40.0)               # beyond max_range: dropped
        events.append((OBSERVATIONS, t, Observations(ranges, np.append(y[seen, 1], 0.0), np.append(ids, 3))))
    return sim, config, truth, stamps, odom, events


def test_odometry_model_recovers_noise_free_landmarks():
    sim, config, truth, stamps, odom, events = _odometry_run()
    result = batch_from_inputs(events, config, truth[0])
    np.testing.assert_allclose(result.stamps, stamps[::SUB], atol=1e-12)
    np.testing.assert_allclose(result.poses[:, :2], truth[::SUB, :2], atol=1e-6)
    np.testing.assert_allclose(np.cos(result.poses[:, 2] - truth[::SUB, 2]), 1.0, atol=1e-12)
    assert result.landmark_ids.size >= 5
    np.testing.assert_allclose(result.landmarks, sim.landmarks[result.landmark_ids], atol=1e-6)
    n_scans = len(stamps[::SUB]) - 1
    assert result.skipped["unknown_id"] == n_scans and result.skipped["observation_out_of_range"] == n_scans


def test_odometry_compounding_equals_the_estimators_integration():
    """Between scans k and k+1: the SUB increments, each over the time since the previous
    input, integrated by integrate_segments from the world pose at scan k, plus one jitter."""
    sim, config, truth, stamps, odom, events = _odometry_run()
    problem = collect_problem(events, config)
    checked = 0
    for k in range(1, len(problem.increments)):
        i = k * SUB                                       # odometry index of scan k
        increments = np.array([odometry_increment(odom[j - 1], odom[j]) for j in range(i + 1, i + SUB + 1)])
        dts = np.diff(stamps[i:i + SUB + 1])
        start = truth[i][None]
        mean, cov = integrate_segments(config.motion, start, np.zeros((1, 3, 3)), increments, dts)
        to_body = _rotation(-truth[i, 2])
        np.testing.assert_allclose(problem.increments[k], to_body @ (mean[0] - start[0]), atol=1e-10)
        expected = to_body @ cov[0] @ to_body.T + step_jitter(config.motion)
        np.testing.assert_allclose(problem.motion_covariances[k], expected, rtol=1e-10, atol=1e-16)
        checked += np.abs(expected[:2, 2]).max() > 1e-6     # the heading couples in
    assert checked > 5


# --------------------------------------------------------------------------- control model, irregular stamps

class _RecordingSlam(OnlineEMSlam):
    """Records each filter step's transition from particle 0's anchor, in its body frame
    (noise learning off: the configured motion noise is the one in use)."""

    def _filter_step(self, obs, report=None):
        self._flush_motion()
        anchor = self._particles[0]
        to_body = _rotation(-anchor[2])
        trans_cov = self._pred_cov[0] + step_jitter(self.config.motion)
        self.recorded.append((to_body @ (self._pred_mean[0] - anchor), to_body @ trans_cov @ to_body.T))
        super()._filter_step(obs, report)


def test_control_compounding_is_the_estimators_transition(scenario):
    rng = np.random.default_rng(5)
    config = slam_config_for(scenario)
    config = replace(config, motion=replace(config.motion, max_step=0.15, max_prediction_interval=10.0,
                                            sigma_heading=0.01),
                     noise_learning=replace(config.noise_learning, learn=())).validate()
    events, t = [], 0.0
    for k in range(40):
        for _ in range(rng.integers(1 if k == 0 else 0, 4)):     # 0-3 controls per scan, some gaps > max_step
            t += rng.uniform(0.02, 0.3)
            events.append((CONTROL, t, (rng.uniform(1, 4), rng.uniform(-0.3, 0.3))))
        t += rng.uniform(0.02, 0.3)
        events.append((OBSERVATIONS, t, Observations([10.0], [0.1], [k % 3])))
    slam = _RecordingSlam(config, initial_pose=(0.0, 0.0, 0.4))
    slam.recorded = []
    for kind, stamp, payload in events:
        (slam.add_control if kind == CONTROL else slam.add_observations)(stamp, payload)
    problem = collect_problem(events, config)
    assert len(problem.increments) == len(slam.recorded) == 40
    for increment, cov, (expected_increment, expected_cov) in zip(problem.increments, problem.motion_covariances,
                                                                  slam.recorded):
        np.testing.assert_allclose(increment, expected_increment, atol=1e-10)
        np.testing.assert_allclose(cov, expected_cov, rtol=1e-8, atol=1e-14)
    assert problem.skipped["large_time_step_clipped"] == slam.drops["large_time_step_clipped"] > 0


def test_lever_arm_recovers_noise_free_landmarks():
    sim, config, truth, stamps, odom, events = _odometry_run(offset=(0.8, -0.4, 0.1), n_steps=30)
    result = batch_from_inputs(events, config, truth[0])
    np.testing.assert_allclose(result.poses[:, :2], truth[::SUB, :2], atol=1e-6)
    np.testing.assert_allclose(result.landmarks, sim.landmarks[result.landmark_ids], atol=1e-6)


# --------------------------------------------------------------------------- the estimator's model

def test_minimum_travel_leaves_out_the_scans_the_feeder_would():
    """With filter.minimum_travel_distance, a scan gets a pose variable only once the robot has
    moved that far since the last used one (the first is used): kept scans found from the true
    (noise-free) poses, and the truth recovered at them through the merged motion."""
    sim, config, truth, stamps, odom, events = _odometry_run()
    config = replace(config, filter=replace(config.filter, minimum_travel_distance=2.0)).validate()
    scans = np.arange(SUB, len(stamps), SUB)
    kept = [scans[0]]
    for i in scans[1:]:
        if np.hypot(*(truth[i, :2] - truth[kept[-1], :2])) >= 2.0:
            kept.append(i)
    assert 3 < len(kept) < len(scans) // 2
    result = batch_from_inputs(events, config, truth[0])
    np.testing.assert_allclose(result.stamps[1:], stamps[kept], atol=1e-12)
    assert result.skipped["minimum_travel"] == len(scans) - len(kept)
    np.testing.assert_allclose(result.poses[1:, :2], truth[kept, :2], atol=1e-6)
    np.testing.assert_allclose(result.landmarks, sim.landmarks[result.landmark_ids], atol=1e-6)


def test_student_t_observation_costs_its_negative_log_likelihood():
    """The robust kernel is the t's -log density up to a constant, (nu + 2) / 2 log(1 + d2 / nu),
    d2 under R; the Gaussian keeps R."""
    from online_em_slam.core.config import ObservationNoiseConfig
    from online_em_slam.offline.observation_factors import observation_noise_model
    R = np.array([[0.04, 0.003], [0.003, 0.0009]])
    rng = np.random.default_rng(3)
    for nu in (3.0, 4.0, 30.0):
        model = observation_noise_model(gtsam, R, ObservationNoiseConfig(model="student_t", dof=nu))
        for e in rng.normal(size=(5, 2)) * [0.5, 0.1]:
            d2 = e @ np.linalg.solve(R, e)
            assert model.loss(model.squaredMahalanobisDistance(e)) == pytest.approx(0.5 * (nu + 2) * np.log1p(d2 / nu))
    gaussian = observation_noise_model(gtsam, R, ObservationNoiseConfig(model="gaussian"))
    e = np.array([0.1, -0.02])
    assert gaussian.squaredMahalanobisDistance(e) == pytest.approx(e @ np.linalg.solve(R, e))
