"""The node's /diagnostics: update and input rates, latency, drops by reason, load.

The statistics are counted over a window that restarts at each publication
(``diagnostics_period``); the status turns WARN while paused, when inputs were
dropped since the last publication or when an input stream went silent, and ERROR
when inputs flowed and then every one has been silent for ``input_timeout``.  The
estimator's decisions about valid input (core/types.py ``DECISIONS``: empty clouds,
ambiguous associations, ...) are counted under ``decided.*`` and leave it OK.
"""
from __future__ import annotations

import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import QoSProfile
from std_msgs.msg import Header

from ..core.types import split_decisions
from . import conversions as conv
from .input_watch import publishers_text


class Diagnostics:
    """Statistics of the node's work and their publication (``node``: OnlineEmSlamNode)."""

    def __init__(self, node) -> None:
        self.node = node
        self.updates = self.inputs = 0
        self.window_start = time.monotonic()
        self.window_updates = self.window_inputs = 0
        self.latencies: list[float] = []
        self.queue_wait_max = self.queue_wait_peak = 0.0   # s an input waited in its subscription's queue
        self.last_ess = float("nan")
        self.resets = 0
        self.drops_reported = 0
        self.publisher = node.create_publisher(DiagnosticArray, "/diagnostics", QoSProfile(depth=10))

    # ------------------------------------------------------------------ counting
    def count_input(self) -> None:
        """A well-formed input was received."""
        self.inputs += 1
        self.window_inputs += 1

    def updated(self, report) -> None:
        """An observation update was applied (``report``: its StepReport)."""
        if math.isfinite(report.ess):
            self.last_ess = float(report.ess)
        self.updates += 1
        self.window_updates += 1

    def latency(self, seconds: float) -> None:
        """Arrival of an input to its use by the estimator."""
        self.latencies.append(seconds)

    def waited(self, seconds: float) -> None:
        """An input waited ``seconds`` in its subscription's queue before it was read."""
        self.queue_wait_max = max(self.queue_wait_max, seconds)
        self.queue_wait_peak = max(self.queue_wait_peak, seconds)

    def count_reset(self) -> None:
        self.last_ess = float("nan")
        self.resets += 1

    # ------------------------------------------------------------------ publication
    def _silent_inputs(self, inputs, level, message):
        """Name every subscribed topic that is silent: heard and stopped (WARN), or never heard
        (WARN when another input arrives: its topic name is likely wrong)."""
        node = self.node
        watch, now, timeout = inputs.watch, time.monotonic(), node.settings.input_delay
        stale = watch.stale(now, timeout)
        unheard = watch.unheard(now, timeout)
        if node.paused:
            return level, message
        silent_for = watch.all_silent_for(now)
        if 0.0 < node.settings.input_timeout < silent_for:
            level = DiagnosticStatus.ERROR
            message += f"; no input for {silent_for:.0f} s"
        if stale:
            level = max(level, DiagnosticStatus.WARN)
            message += "; silent inputs: " + ", ".join(f"{name} for {age:.1f} s" for name, age in stale)
        if unheard:
            if watch.any_heard() and any(stream.required for stream in unheard):
                level = max(level, DiagnosticStatus.WARN)
            message += "; nothing received on: " + ", ".join(
                f"{s.topic} ({s.parameter}, {publishers_text(inputs.publishers(s))}{'' if s.required else ', optional'})"
                for s in unheard)
        return level, message

    def publish(self) -> None:
        """One DiagnosticArray of the window since the last publication; the window restarts."""
        node = self.node
        with node.lock:
            now = time.monotonic()
            span = max(now - self.window_start, 1e-6)
            drops, decided = split_decisions(node.all_drops())
            values = self._values(now, span, drops, decided)
            level, message = self._level(span, values["dropped_total"], values["landmarks"])
            self.drops_reported = values["dropped_total"]
            self._restart_window(now)
            self.publisher.publish(DiagnosticArray(header=Header(stamp=conv.sec_to_stamp(self._stamp())),
                                                   status=[self._status(level, message, values)]))

    def _values(self, now: float, span: float, drops: dict, decided: dict) -> dict:
        """Every key of the status: the window's rates and latencies, the estimator's state, the
        learned noise, a fleet's per-robot values, and the counts by reason."""
        node, slam, inputs = self.node, self.node.slam, self.node.inputs
        latencies = np.asarray(self.latencies) if self.latencies else np.zeros(0)
        landmarks = slam.landmarks()
        values = {
            "update_rate_hz": self.window_updates / span,
            "input_rate_hz": self.window_inputs / span,
            "latency_mean_ms": 1e3 * float(latencies.mean()) if latencies.size else 0.0,
            "latency_max_ms": 1e3 * float(latencies.max()) if latencies.size else 0.0,
            "queue_wait_max_ms": 1e3 * self.queue_wait_max,
            "queue_wait_peak_ms": 1e3 * self.queue_wait_peak,
            "ess": self.last_ess if math.isfinite(self.last_ess) else float(node.config.filter.num_particles),
            "num_particles": slam.config.filter.num_particles,
            "landmarks": len(landmarks),
            "confirmed_landmarks": int(np.count_nonzero(landmarks.confirmed)),
            "observation_updates": self.updates,
            "inputs": self.inputs,
            "queued_inputs": len(inputs.pipeline),
            "load": inputs.pipeline.current_load(now),
            "load_max": inputs.pipeline.max_load,
            "paused": node.paused,
            "resets": self.resets,
            "last_stamp": slam.last_stamp if slam.last_stamp is not None else -1.0,
            "dropped_total": sum(drops.values()),
            "decided_total": sum(decided.values()),
        }
        learned = slam.learned_noise()              # noise learned online (core/em/noise/)
        if learned["enabled"]:
            values.update({f"noise_learned.{k}": v for k, v in learned.items() if k not in ("enabled", "learning")})
        if node.fleet_mode:                         # each robot's ESS, stamp, learned noise, inputs
            values.update(slam.robot_diagnostics())
            values.update({f"inputs.{robot}": count for robot, count in inputs.received().items()})
        if node.segment_link is not None:           # distributed fleet mode: segments.*
            values.update(node.segment_link.diagnostics())
        values.update({f"dropped.{reason}": count for reason, count in sorted(drops.items())})
        values.update({f"decided.{reason}": count for reason, count in sorted(decided.items())})
        values.update({f"corrected.{reason}": count for reason, count in sorted(inputs.corrected.items())})
        values.update(inputs.frames.diagnostics())  # unexpected_frame.*, unexpected_child_frame.*
        return values

    def _level(self, span: float, dropped: int, landmarks: int) -> tuple[int, str]:
        """(level, message): WARN while paused or when inputs were dropped in the window, then
        what the input streams' silence adds (:meth:`_silent_inputs`)."""
        level, message = DiagnosticStatus.OK, f"{landmarks} landmarks"
        if self.node.paused:
            level, message = DiagnosticStatus.WARN, "paused"
        elif dropped > self.drops_reported:
            level = DiagnosticStatus.WARN
            message += f", {dropped - self.drops_reported} inputs dropped in the last {span:.1f} s"
        elif self.updates == 0:
            message = "waiting for observations"
        return self._silent_inputs(self.node.inputs, level, message)

    def _restart_window(self, now: float) -> None:
        self.window_start, self.window_updates, self.window_inputs = now, 0, 0
        self.latencies = []
        self.queue_wait_max = 0.0

    def _stamp(self) -> float:
        """The node's clock, or the estimator's last stamp while the clock is at zero (sim time
        before /clock)."""
        stamp, last = self.node.now_sec(), self.node.slam.last_stamp
        return last if stamp <= 0.0 and last is not None else stamp

    def _status(self, level: int, message: str, values: dict) -> DiagnosticStatus:
        node = self.node
        return DiagnosticStatus(
            level=level, name=f"{node.get_name()}: online EM SLAM", message=message,
            hardware_id=node.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=(f"{v:.6g}" if isinstance(v, float) else str(v))) for k, v in values.items()])
