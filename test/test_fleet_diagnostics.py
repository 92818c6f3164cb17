"""Fleet mode's /diagnostics count each robot's inputs (``inputs.<robot>``) next to the node's
``inputs`` (issue 25: the replay check compares them with what the replay published per robot).
Fast: stubs, no ROS."""
from __future__ import annotations

from types import SimpleNamespace


class _Shared:
    def __init__(self):
        self.inputs = 0
        self.latencies = []

    def count_input(self):
        self.inputs += 1

    def latency(self, seconds):
        self.latencies.append(seconds)


def test_robot_diagnostics_count_the_robot_and_the_node():
    from online_em_slam.ros.fleet_robot import RobotDiagnostics

    shared = _Shared()
    one, two = RobotDiagnostics(shared), RobotDiagnostics(shared)
    for _ in range(3):
        one.count_input()
    two.count_input()
    two.latency(0.5)                       # everything else goes to the node's diagnostics
    assert (one.inputs, two.inputs, shared.inputs) == (3, 1, 4)
    assert shared.latencies == [0.5]


def test_fleet_inputs_report_received_per_robot():
    from online_em_slam.ros.fleet_inputs import FleetInputs
    from online_em_slam.ros.fleet_robot import RobotDiagnostics

    shared = _Shared()
    robots = [SimpleNamespace(name=f"robot{k}", diagnostics=RobotDiagnostics(shared)) for k in (1, 2)]
    robots[1].diagnostics.count_input()
    inputs = FleetInputs.__new__(FleetInputs)
    inputs.robots = robots
    assert inputs.received() == {"robot1": 0, "robot2": 1}
