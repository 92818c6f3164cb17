"""The distributed fleet's segment messages as bytes (messages/segments.py): a node that folds
decoded messages holds the same map as one folding the objects, and bad bytes are refused."""
import io

import numpy as np
import pytest

from online_em_slam.core import FleetSlam
from online_em_slam.experiments.simulation import ScenarioConfig, feed, fleet_scenarios, slam_config_for
from online_em_slam.messages import segments
from test_fleet import _Robot


def _messages():
    """Robot 1's messages (segments and its restart) from a node that drives it, and that node."""
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=120, seed=1), 2)
    config = slam_config_for(scenarios[0], num_particles=30, seed=0)
    node = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    node.share_segments()
    for k in range(scenarios[1].n_steps):
        feed(_Robot(node, 1), scenarios[1].steps[k])
    node.relocalise(1, node.pose(1).mean, [0.5, 0.5, 0.1])
    return scenarios, config, node.outgoing()


def test_decoded_messages_fold_to_the_same_map_bit_for_bit():
    scenarios, config, messages = _messages()
    assert any(m.segment is None for m in messages) and sum(m.segment is not None for m in messages) > 3
    direct = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    decoded = FleetSlam(config, [s.initial_pose for s in scenarios], stamp=0.0)
    for message in messages:
        direct.fold_remote(message)
        envelope = segments.decode(segments.encode(message, "robot2", 12345))
        assert (envelope.robot, envelope.session, envelope.message.sequence) == ("robot2", 12345, message.sequence)
        envelope.message.robot = message.robot
        decoded.fold_remote(envelope.message)
    a, b = direct.landmarks(), decoded.landmarks()
    assert np.array_equal(a.ids, b.ids) and np.array_equal(a.positions, b.positions)
    assert np.array_equal(a.covariances, b.covariances)


def _field(data: bytes, name: str) -> np.ndarray:
    with np.load(io.BytesIO(data)) as archive:
        return archive[name]


def _corrupt(data: bytes, **changes) -> bytes:
    with np.load(io.BytesIO(data)) as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays.update(changes)
    out = io.BytesIO()
    np.savez(out, **{k: v for k, v in arrays.items() if v is not None})
    return out.getvalue()


@pytest.mark.parametrize("bad, reason", [
    (lambda d: b"not a zip", "not a segment message"),
    (lambda d: d[: len(d) // 2], "not a segment message"),
    (lambda d: _corrupt(d, format=np.array("other.v9")), "format"),
    (lambda d: _corrupt(d, robot=None), "without 'robot'"),
    (lambda d: _corrupt(d, sequence=np.array(0)), "bad sequence"),
    (lambda d: _corrupt(d, segment_local=np.full((5, 5), np.nan)), "shapes"),
    (lambda d: _corrupt(d, segment_key=np.array([0.0, np.inf, 0.0])), "not finite"),
    (lambda d: _corrupt(d, segment_local=np.array(["x"])), "wrong type"),
    (lambda d: _corrupt(d, ids=np.full(_field(d, "ids").size, 3)), "twice"),
])
def test_bad_bytes_are_refused_with_a_reason(bad, reason):
    _, _, messages = _messages()
    data = segments.encode(next(m for m in messages if m.segment is not None), "robot2", 1)
    with pytest.raises(ValueError, match=reason):
        segments.decode(bad(data))


def test_a_restart_without_a_pose_is_refused():
    _, _, messages = _messages()
    data = segments.encode(next(m for m in messages if m.segment is None), "robot2", 1)
    with pytest.raises(ValueError, match="finite pose and std"):
        segments.decode(_corrupt(data, pose_std=np.array([0.1, -1.0, 0.1])))
