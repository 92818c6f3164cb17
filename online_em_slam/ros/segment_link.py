"""Distributed fleet mode: this node's map information out, the other nodes' in (docs/NODE.md,
"Distributed fleet").

One node per robot (``local_robot``), every node listing the same ``robots``.  Each
closed segment of this node's robot is one message on ``segments_topic`` (reliable,
transient local: a node that starts late gets the recent ones); each other robot's
message is folded into this node's map (FleetEstimate.fold_remote), so every node
holds the product of every robot's segment factors, up to the messages in flight.

Each sending estimator draws a ``session`` number (FleetEstimate.session), and numbers its messages per robot
from 1.  A message already folded (same session, a number not above the last) is a
duplicate and skipped: they come back after a rollback of the sender or a re-subscription.
A gap in the numbers is a lost message; the core restarts that robot's key block
(ObservedInformationEM.fold_remote), so a loss costs accuracy, never consistency.  A new
session (the other node reset) restarts the key block the same way.  What cannot be
used (malformed, an unknown robot, a fold that fails) is dropped and counted.
"""
from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import replace

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import MultiArrayDimension, MultiArrayLayout, UInt8MultiArray

from ..messages import segments

DEPTH = 1000        # messages kept for a late subscriber: some minutes of one robot's segments
PERIOD = 0.05       # s between sends (steady clock)


def segments_qos() -> QoSProfile:
    return QoSProfile(depth=DEPTH, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class SegmentLink:
    """Publishes this node's segments and folds in the other nodes' (``node``: OnlineEmSlamNode
    in the distributed fleet mode); its counters go to /diagnostics under ``segments.*``."""

    def __init__(self, node) -> None:
        s = node.settings
        self.node = node
        self.robot = s.local_robot
        self.index_of = {name: r for r, name in enumerate(s.robots)}
        self.counts: Counter = Counter()
        self.publisher = node.create_publisher(UInt8MultiArray, s.segments_topic, segments_qos())
        self.subscription = node.create_subscription(UInt8MultiArray, s.segments_topic, self.receive,
                                                     segments_qos())

    def send(self) -> None:
        """Publish the segments closed since the last call (timer callback)."""
        with self.node.lock:
            estimate = self.node.slam
            messages = estimate.outgoing()
        for message in messages:
            data = segments.encode(message, self.robot, estimate.session)
            layout = MultiArrayLayout(dim=[MultiArrayDimension(label=segments.FORMAT, size=len(data), stride=1)])
            self.publisher.publish(UInt8MultiArray(layout=layout, data=array("B", data)))
            self.counts["sent"] += 1

    def receive(self, msg: UInt8MultiArray) -> None:
        node = self.node
        try:
            envelope = segments.decode(msg.data.tobytes() if hasattr(msg.data, "tobytes") else bytes(msg.data))
        except ValueError as error:
            self._drop("segment_malformed", f"a segment message was refused: {error}")
            return
        if envelope.robot == self.robot:
            if envelope.session != node.slam.session:
                self._drop("segment_same_robot", f"another node also drives {self.robot} (same local_robot)")
            return
        if envelope.robot not in self.index_of:
            self._drop("segment_unknown_robot", f"a segment of robot {envelope.robot!r}, not one of robots")
            return
        message = replace(envelope.message, robot=self.index_of[envelope.robot])
        with node.lock:
            estimate = node.slam
            if not self._new(estimate, envelope):
                self.counts["duplicate"] += 1
                return
            try:
                estimate.fold_remote(message)
            except Exception as error:  # noqa: BLE001 - the rollback undid it; one message must not stop the node
                self._drop("segment_failed", f"folding {envelope.robot}'s segment failed: {error!r}")
                lost = estimate.take_lost()
                if lost:
                    node.drops["reapply_failed"] += lost
                return
            estimate.received[envelope.robot] = (envelope.session, message.sequence)
            node.outputs.map_dirty = True
        self.counts["folded"] += 1

    def _new(self, estimate, envelope) -> bool:
        """Not folded into this estimator yet (its ``received``: it lives and restarts with the estimator,
        not with this link); counts a gap (lost messages) and logs a sender that started again."""
        last = estimate.received.get(envelope.robot)
        sequence = envelope.message.sequence
        if last is None:
            return True
        if last[0] != envelope.session:
            self.node.get_logger().info(f"{envelope.robot}'s node started a new session: its key pose restarts")
            self.counts["sessions"] += 1
            return True
        if sequence <= last[1]:
            return False
        if sequence > last[1] + 1:
            self.counts["lost"] += sequence - last[1] - 1
            self.node.throttle.warning("segment_lost", f"{sequence - last[1] - 1} segment messages of "
                                       f"{envelope.robot} lost: its key pose restarts (less information)")
        return True

    def _drop(self, reason: str, text: str) -> None:
        with self.node.lock:
            self.node.drops[reason] += 1
        self.node.throttle.warning(reason, text)

    def diagnostics(self) -> dict:
        return {f"segments.{name}": self.counts[name] for name in ("sent", "folded", "duplicate", "lost", "sessions")}
