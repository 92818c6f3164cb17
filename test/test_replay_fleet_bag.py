"""online-em-slam-replay takes a fleet bag (``/robotK/odom``, ... as ``online-em-slam-convert
mrclam --all-robots`` writes it; issue 25): the input check finds the robots' namespaces
instead of refusing a bag without root /odom, /control, /landmark_observations, and checks
the namespaced inputs' types as the root ones.  Fast: check_bag only, no ROS."""
from __future__ import annotations

from collections import Counter

import pytest

from bad_bag_corpus import BASE_TOPICS, _messages
from ros_domain import claim


def write_fleet_bag(path, robots=("/robot1", "/robot2"), wrong: dict | None = None, topics=BASE_TOPICS):
    """The small base bag's inputs once per robot namespace (``wrong``: root topic -> written as String)."""
    from online_em_slam.bag.bagio import jazzy_typestore, write_topics

    ts = jazzy_typestore()
    base = _messages(ts, topics, wrong)
    messages = sorted(((ns, robot + topic, msgtype, msg) for robot in robots for ns, topic, msgtype, msg in base),
                      key=lambda e: (e[0], e[1]))
    counts = Counter(topic for _, topic, _, _ in messages)
    msgtypes = {}
    for _, topic, msgtype, _ in messages:
        msgtypes.setdefault(topic, msgtype)
    write_topics(path, iter(messages), dict(counts), msgtypes, (), ts, progress=False)
    return path


def _check(bag, *argv):
    from online_em_slam.bag import replay

    replay.check_bag(bag, replay.build_parser().parse_args([str(bag), *argv]))


def test_robot_namespaces_need_observations_and_a_motion_input():
    from online_em_slam.bag.replay import robot_namespaces

    motion, obs = ["/odom", "/control"], "/landmark_observations"
    counts = {"/robot1/control": 5, "/robot1/landmark_observations": 2, "/robot2/odom": 3,
              "/robot2/landmark_observations": 1, "/robot3/landmark_observations": 4,
              "/robot4/control": 2, "/robot4/landmark_observations": 0, "/landmark_observations": 7, "/odom": 1}
    assert robot_namespaces(counts, motion, obs) == ["/robot1", "/robot2"]
    assert robot_namespaces({"/odom": 1, "/landmark_observations": 1}, motion, obs) == []


def test_a_fleet_bag_passes_the_input_check(tmp_path):
    _check(write_fleet_bag(tmp_path / "fleet"))
    _check(write_fleet_bag(tmp_path / "fleet_odom", topics=("/odom", "/landmark_observations")),
           "--topics", "/robot1/odom", "/robot1/landmark_observations")


def test_a_fleet_bag_without_observations_is_still_refused(tmp_path):
    from online_em_slam.bag.bagio import BagError

    bag = write_fleet_bag(tmp_path / "fleet", topics=("/control", "/odom"))
    with pytest.raises(BagError, match="no motion input for the node"):
        _check(bag)


def test_a_robot_input_of_the_wrong_type_is_refused(tmp_path):
    from online_em_slam.bag.bagio import BagError

    bag = write_fleet_bag(tmp_path / "fleet", wrong={"/odom": True})
    with pytest.raises(BagError, match="/robot1/odom is std_msgs/msg/String, expected nav_msgs/msg/Odometry"):
        _check(bag)


class _Refusing:
    """A publisher whose middleware refuses the first ``n`` attempts (a full KEEP_ALL history)."""

    def __init__(self, n, error="Failed to publish: cannot publish data, at /project/src/rmw_publish.cpp:116"):
        self.n, self.error, self.sent = n, error, []

    def publish(self, raw):
        if self.n:
            self.n -= 1
            raise RuntimeError(self.error)
        self.sent.append(raw)


def test_a_refused_message_is_retried_not_lost():
    from online_em_slam.bag.replay import publish_waiting

    now = [0.0]

    def sleep(s):
        now[0] += s
    pub = _Refusing(3)
    waited, retries = publish_waiting(pub, b"m", timeout=5.0, sleep=sleep, clock=lambda: now[0])
    assert pub.sent == [b"m"] and retries == 3 and waited > 0
    assert publish_waiting(_Refusing(0), b"m", 5.0, sleep=sleep, clock=lambda: now[0]) == (0.0, 0)


def test_a_subscriber_that_never_acknowledges_ends_the_replay_after_the_timeout():
    from online_em_slam.bag.replay import PublishError, publish_waiting

    now = [0.0]

    def sleep(s):
        now[0] += s
    with pytest.raises(PublishError, match="--publish-timeout"):
        publish_waiting(_Refusing(10 ** 6), b"m", timeout=1.0, sleep=sleep, clock=lambda: now[0])
    with pytest.raises(RuntimeError, match="context is invalid"):      # other errors are not retried
        publish_waiting(_Refusing(1, "publisher's context is invalid"), b"m", 1.0, sleep=sleep)


@pytest.mark.live        # a real rclpy context and DDS participant: with the live tests, not in a shared worker
def test_sigint_while_waiting_for_acknowledgements_ends_with_the_summary(tmp_path, capsys, monkeypatch):
    """rclpy's SIGINT handler shuts the context down while the replay waits for acknowledgements:
    status 130 and the JSON summary, not a traceback (it was 'publisher's context is invalid')."""
    pytest.importorskip("rclpy")
    import json
    import os

    import rclpy

    from online_em_slam.bag import replay

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(claim()))

    def interrupted(publishers, timeout, log):
        rclpy.shutdown()
        raise RuntimeError("failed to get subscription count: publisher's context is invalid")
    monkeypatch.setattr(replay, "_acknowledged", interrupted)
    code = replay.main([str(write_fleet_bag(tmp_path / "fleet")), "--rate", "0", "--quiet"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 130 and summary["interrupted"] and summary["total"] > 0


@pytest.mark.live
def test_sigint_while_publishing_ends_with_the_summary(tmp_path, capsys, monkeypatch):
    """The same inside a publish (seen once in CI: 'Failed to publish: publisher's context is
    invalid' with a traceback and status 1)."""
    pytest.importorskip("rclpy")
    import json

    import rclpy

    from online_em_slam.bag import replay

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(claim()))
    published = []

    def publish(publisher, raw, timeout):
        if len(published) == 5:
            rclpy.shutdown()
            raise RuntimeError("Failed to publish: publisher's context is invalid")
        published.append(raw)
        return 0.0, 0
    monkeypatch.setattr(replay, "publish_waiting", publish)
    code = replay.main([str(write_fleet_bag(tmp_path / "fleet")), "--rate", "0", "--quiet"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 130 and summary["interrupted"] and summary["total"] == 5
    assert summary["wall_seconds"] is not None
