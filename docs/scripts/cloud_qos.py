"""What cloud size each input QoS carries between two processes on one host.

A publisher process sends observation clouds (range, bearing, id: 12 bytes a point) of N
points at RATE Hz for SECONDS; this process subscribes with the node's input QoS
(best_effort KEEP_LAST 1000, or reliable KEEP_ALL) and counts what arrives. The publisher
uses the QoS a detector would (best effort, or reliable). Prints a table and writes JSON.

    python docs/scripts/cloud_qos.py --output docs/measurements/cloud_qos.json
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

POINTS = (100, 1_000, 5_000, 10_000, 50_000, 100_000)
TOPIC = "/cloud_qos_probe"

PUBLISHER = r"""
import sys, time
import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from online_em_slam.messages.cloud import build_message
n, rate, seconds, reliable = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4] == "reliable"
rclpy.init()
node = rclpy.create_node("cloud_qos_publisher")
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                 history=HistoryPolicy.KEEP_LAST)
pub = node.create_publisher(PointCloud2, "%s", qos)
deadline = time.monotonic() + 10.0
while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.5)
columns = {"range": np.full(n, 5.0, np.float32), "bearing": np.zeros(n, np.float32), "id": np.arange(n, dtype=np.int32)}
sent = 0
for k in range(int(rate * seconds)):
    msg = build_message(PointCloud2, PointField, Header(frame_id="sensor"), columns)
    msg.header.stamp.sec = k
    pub.publish(msg)
    sent += 1
    time.sleep(1.0 / rate)
time.sleep(1.0)
print(sent, flush=True)
node.destroy_node()
rclpy.shutdown()
""" % TOPIC


def measure(n: int, rate: float, seconds: float, reliability: str, domain: int) -> dict:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import PointCloud2

    from online_em_slam.ros.node import input_qos

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("cloud_qos_subscriber", context=context)
    received = []
    node.create_subscription(PointCloud2, TOPIC, lambda m: received.append(m.width), input_qos(reliability, 1000))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(n), str(rate), str(seconds), reliability],
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while publisher.poll() is None:
        executor.spin_once(timeout_sec=0.01)
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)
    out, err = publisher.communicate()
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)
    sent = int(out.strip().splitlines()[-1]) if out.strip() else 0
    return {"points": n, "bytes": 12 * n, "qos": reliability, "sent": sent, "received": len(received),
            "complete": all(w == n for w in received)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--domain", type=int, default=77)
    parser.add_argument("--output", default=None)
    args = parser.parse_args(argv)
    rows = [measure(n, args.rate, args.seconds, q, args.domain) for q in ("best_effort", "reliable") for n in POINTS]
    print("| points | bytes | input QoS | sent | received |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['points']:,} | {r['bytes']:,} | {r['qos']} | {r['sent']} | {r['received']} |")
    if args.output:
        with open(args.output, "w") as f:
            json.dump({"rate_hz": args.rate, "seconds": args.seconds, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
