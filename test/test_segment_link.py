"""The distributed mode's link in one process (ros/segment_link.py): two nodes, one per robot.
A node re-activated gets the other's history again (transient local) and folds none of it
twice; bad messages on the topic are counted drops."""
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import TwistStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import Header, UInt8MultiArray  # noqa: E402

from online_em_slam.experiments.simulation import ScenarioConfig, fleet_scenarios  # noqa: E402
from online_em_slam.ros import conversions as conv  # noqa: E402
from online_em_slam.ros.node import OnlineEmSlamNode  # noqa: E402
from online_em_slam.ros.segment_link import segments_qos  # noqa: E402
from test_node import LIVE_DEFAULTS, T0  # noqa: E402
from test_node_fleet import _model  # noqa: E402

ROBOTS = ("robot1", "robot2")


def _nodes(ros, scenarios):
    poses = [float(v) for s in scenarios for v in s.initial_pose]
    params = {**LIVE_DEFAULTS, "input_delay": 1.0, "motion_source": "control", "control_angular": "steering",
              "filter.num_particles": 20, "robots": list(ROBOTS), "initial_poses": poses, **_model(scenarios[0].config)}
    nodes = {}
    for r in ROBOTS:
        overrides = [Parameter(k, value=v) for k, v in {**params, "local_robot": r}.items()]
        nodes[r] = OnlineEmSlamNode(f"slam_{r}", context=ros.context, parameter_overrides=overrides)
        ros.executor.add_node(nodes[r])
    ros.node = nodes["robot1"]
    return nodes


def _publish(ros, scenarios, steps) -> None:
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {r: (ros.tester.create_publisher(TwistStamped, f"/{r}/control", qos),
                ros.tester.create_publisher(PointCloud2, f"/{r}/landmark_observations", qos)) for r in ROBOTS}
    for k in steps:
        for r, scenario in zip(ROBOTS, scenarios):
            step = scenario.steps[k]
            msg = TwistStamped(header=Header(stamp=conv.sec_to_stamp(T0 + step.control_stamp)))
            msg.twist.linear.x, msg.twist.angular.z = (float(v) for v in step.control)
            pubs[r][0].publish(msg)
            pubs[r][1].publish(conv.observations_to_cloud(Header(stamp=conv.sec_to_stamp(T0 + step.stamp)),
                                                          step.ranges, step.bearings, step.ids))
        ros.spin_for(0.01)


def _exchanged(nodes) -> bool:
    a, b = (nodes[r].segment_link.counts for r in ROBOTS)
    return a["sent"] > 0 and a["folded"] == b["sent"] and b["folded"] == a["sent"]


def test_a_reactivated_node_folds_nothing_twice_and_bad_messages_are_dropped(ros):
    scenarios = fleet_scenarios(ScenarioConfig(n_steps=120, seed=0), 2)
    nodes = _nodes(ros, scenarios)
    _publish(ros, scenarios, range(60))
    assert ros.spin_until(lambda: _exchanged(nodes), 20.0), [dict(nodes[r].segment_link.counts) for r in ROBOTS]
    node, other = nodes["robot1"], nodes["robot2"]
    before = node.slam.landmarks().positions.copy()
    sent_before = node.segment_link.counts["sent"]

    node.trigger_deactivate()
    node.trigger_activate()                       # a new link: robot2's history comes again
    history = other.segment_link.counts["sent"]
    assert ros.spin_until(lambda: node.segment_link.counts["duplicate"] == history, 10.0), node.segment_link.counts
    assert node.segment_link.counts["folded"] == 0 and np.array_equal(node.slam.landmarks().positions, before)

    bad = ros.tester.create_publisher(UInt8MultiArray, "/fleet/map_segments", segments_qos())
    bad.publish(UInt8MultiArray(data=b"not a segment"))
    assert ros.spin_until(lambda: node.all_drops().get("segment_malformed") == 1, 5.0), node.all_drops()

    _publish(ros, scenarios, range(60, 120))

    def exchanged() -> bool:
        mine, theirs = node.segment_link.counts, other.segment_link.counts
        return (theirs["sent"] > history and mine["folded"] == theirs["sent"] - history
                and theirs["folded"] == sent_before + mine["sent"])
    try:
        assert ros.spin_until(exchanged, 20.0), (node.segment_link.counts, other.segment_link.counts)
        assert node.segment_link.counts["lost"] == 0 and other.segment_link.counts["lost"] == 0
        a, b = node.slam.landmarks(), other.slam.landmarks()
        # The 120 scans close every segment, and both maps are then the same (0.0000 m apart). Under
        # load a node may end with a segment still open, whose landmarks are its own view until it
        # closes (in CI once a landmark only one node held, once a common one 0.53 m apart; with two
        # CPU hogs beside the test, a landmark only one held, also with lossless inputs). So most
        # landmarks, not every one, must agree exactly.
        assert np.isfinite(a.positions).all()
        only = set(a.ids.tolist()) ^ set(b.ids.tolist())
        assert len(only) <= 3, only
        where = {i: k for k, i in enumerate(b.ids.tolist())}
        apart = np.array([np.hypot(*(p - b.positions[where[i]])) for i, p in zip(a.ids.tolist(), a.positions)
                          if i in where])
        print(f"the two nodes' maps {np.median(apart):.4f} m apart (median), {apart.max():.4f} m at most")
        assert np.median(apart) < 0.01 and apart.max() < 1.0
    finally:
        ros.executor.remove_node(other)
        other.destroy_node()
