"""ROS environment for in-process rclpy tests (must be set before rclpy is imported)."""
import os

# All test nodes live in one process and context: no discovery outside it, so
# concurrent test runs on this host cannot see each other's topics.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")

import pytest  # noqa: E402

from ros_domain import claim  # noqa: E402

# This test process's own domain: the multi-process tests turn discovery on (LOCALHOST), and
# any other run on this host with the same domain would then publish into their nodes.
os.environ["ROS_DOMAIN_ID"] = str(claim())

# Tests that run live nodes against the wall clock (in this process or in others).  `make test`
# runs them on their own after the others, which it runs on two workers: a live node's timing
# tolerances hold on a machine that is not also filtering in another process.
LIVE_MODULES = {"test_node", "test_node_inputs", "test_node_user", "test_node_lifecycle", "test_fuzz_node",
                "test_reliability_node", "test_replay", "test_replay_options", "test_tools",
                "test_tf_tree", "test_tf_sensor_pose", "test_tf_wheels"}


def pytest_configure(config):
    config.addinivalue_line("markers", "live: runs live ROS nodes against the wall clock")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.module.__name__ in LIVE_MODULES or "ros" in item.fixturenames:
            item.add_marker(pytest.mark.live)


@pytest.fixture
def no_discovery(monkeypatch):
    """Discovery off for a test whose nodes all live in this process.  Set per test, not at
    import: a module setting it at import would undo test_replay.py's LOCALHOST for its
    multi-process tests when the whole suite is collected."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")


@pytest.fixture
def ros():
    """A live node harness (test_node.Harness) in a fresh rclpy Context, shut down after the test."""
    pytest.importorskip("rclpy")
    from test_node import Harness
    harness = Harness()
    try:
        yield harness
    finally:
        harness.close()
