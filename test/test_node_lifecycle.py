"""The node as a managed (lifecycle) node, live: every transition through the lifecycle
services a lifecycle manager (or ``ros2 lifecycle set``) uses, and ``autostart``."""
import pytest

rclpy = pytest.importorskip("rclpy")
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from online_em_slam.ros.node import OnlineEmSlamNode  # noqa: E402
from test_node import NAME, T0  # noqa: E402


def _ours(node, kind: str) -> set[str]:
    """The node's own topics of ``kind`` (publishers or subscriptions), lifecycle services aside."""
    entities = node.publishers if kind == "publishers" else node.subscriptions
    return {e.topic_name for e in entities
            if "transition_event" not in e.topic_name and e.topic_name not in ("/parameter_events", "/rosout")}


def test_every_transition_of_the_managed_node(ros):
    node = ros.node = OnlineEmSlamNode(context=ros.context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("diagnostics_period", value=0.2),
        Parameter("input_delay", value=0.0)])
    ros.executor.add_node(node)

    def state() -> str:
        return ros.call(GetState, "get_state", GetState.Request()).current_state.label

    def change(transition: int) -> None:
        assert ros.call(ChangeState, "change_state", ChangeState.Request(
            transition=Transition(id=transition))).success

    assert state() == "unconfigured" and not _ours(node, "publishers") and not _ours(node, "subscriptions")
    change(Transition.TRANSITION_CONFIGURE)
    assert state() == "inactive"
    assert f"/{NAME}/pose" in _ours(node, "publishers") and "/odom" not in _ours(node, "subscriptions")
    change(Transition.TRANSITION_ACTIVATE)
    assert state() == "active" and {"/odom", "/landmark_observations"} <= _ours(node, "subscriptions")

    publisher = ros.tester.create_publisher(_odometry_type(), "/odom", 100)
    assert ros.spin_until(lambda: publisher.get_subscription_count() == 1, 5.0)
    for k in range(5):
        publisher.publish(_odometry(T0 + 0.1 * k, 0.1 * k))
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 0.4), 5.0)

    change(Transition.TRANSITION_DEACTIVATE)                       # inputs stop; the estimate stays
    assert state() == "inactive" and "/odom" not in _ours(node, "subscriptions")
    for k in range(5, 8):
        publisher.publish(_odometry(T0 + 0.1 * k, 0.1 * k))
    ros.spin_for(0.3)
    assert node.slam.last_stamp == pytest.approx(T0 + 0.4)
    change(Transition.TRANSITION_ACTIVATE)                         # and go on from where it was
    assert ros.spin_until(lambda: publisher.get_subscription_count() == 1, 5.0)
    publisher.publish(_odometry(T0 + 0.9, 0.9))
    assert ros.spin_until(lambda: node.slam.last_stamp == pytest.approx(T0 + 0.9), 5.0)
    assert node.slam.pose().mean[0] == pytest.approx(0.9, abs=0.05)

    change(Transition.TRANSITION_DEACTIVATE)
    change(Transition.TRANSITION_CLEANUP)                          # everything configure made is gone
    assert state() == "unconfigured" and not _ours(node, "publishers") and not _ours(node, "subscriptions")
    change(Transition.TRANSITION_CONFIGURE)                        # and can be made again
    change(Transition.TRANSITION_ACTIVATE)
    assert state() == "active" and node.slam.last_stamp is None
    change(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    assert state() == "finalized" and not _ours(node, "subscriptions")


def test_autostart_maps_at_once(ros):
    ros.start()                                                    # autostart: true, the default
    assert ros.call(GetState, "get_state", GetState.Request()).current_state.label == "active"


def _odometry_type():
    from nav_msgs.msg import Odometry
    return Odometry


def _odometry(stamp: float, x: float):
    from online_em_slam.ros import conversions as conv
    msg = _odometry_type()()
    msg.header.stamp = conv.sec_to_stamp(stamp)
    msg.header.frame_id = "odom"
    msg.pose.pose.position.x = float(x)
    msg.pose.pose.orientation.w = 1.0
    return msg


def test_a_namespaced_node_takes_initialpose_in_its_namespace(ros):
    """ROS-conventions item 7: under namespace robot1 the node listens on /robot1/initialpose
    (as AMCL), so two robots' RViz poses do not mix; without a namespace it is /initialpose."""
    node = ros.node = OnlineEmSlamNode(context=ros.context, namespace="robot1")
    ros.executor.add_node(node)
    topics = {s.topic_name for s in node.subscriptions}
    assert "/robot1/initialpose" in topics and "/initialpose" not in topics
    assert "/robot1/odom" in topics
