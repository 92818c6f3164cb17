"""Wall time from an empty interpreter to the node constructed, configured and active.

    python docs/scripts/node_start_time.py

The node's ``autostart`` (default true) configures and activates it in its constructor.
Printed: the imports (rclpy and the node's modules), then the construction with both
transitions (docs/BENCHMARKS.md, "Compiled kernels"; where the imports go:
``python -X importtime -c "from online_em_slam.ros.node import OnlineEmSlamNode"``).
"""
import time

T0 = time.perf_counter()
import os  # noqa: E402

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")    # one process: no discovery to wait for
import rclpy  # noqa: E402

from online_em_slam.ros.node import OnlineEmSlamNode  # noqa: E402


def main() -> None:
    imported = time.perf_counter()
    rclpy.init()
    node = OnlineEmSlamNode()
    active = time.perf_counter()
    print(f"imports {imported - T0:.3f} s, construct + configure + activate {active - imported:.3f} s, "
          f"total {active - T0:.3f} s")
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
