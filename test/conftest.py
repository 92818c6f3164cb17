"""ROS environment for in-process rclpy tests (must be set before rclpy is imported)."""
import os

# All test nodes live in one process and context: no discovery outside it, so
# concurrent test runs on this host cannot see each other's topics.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")

import pytest  # noqa: E402


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
