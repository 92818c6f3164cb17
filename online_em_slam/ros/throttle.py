"""Throttled log messages that cost nothing while throttled.

rclpy's ``throttle_duration_sec`` identifies its call site on every call (a frame
walk and a realpath, about half a millisecond), so a warning repeated per input
during a flood of bad or late inputs cost the node more than the estimator did.
:class:`Throttle` keeps its own clock per key and calls the logger only when a
message is due.
"""
from __future__ import annotations

import time
from typing import Callable


class Throttle:
    """``logger``: returns the rclpy logger; ``period``: returns the throttle period (s, wall)."""

    def __init__(self, logger: Callable, period: Callable[[], float],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.period = period
        self.clock = clock
        self._last: dict[str, float] = {}

    def due(self, key: str, period: float | None = None) -> bool:
        """True at most once per ``period`` (default: the node's) for ``key``; marks it sent."""
        now = self.clock()
        last = self._last.get(key)
        if last is not None and now - last < (self.period() if period is None else period):
            return False
        self._last[key] = now
        return True

    def warning(self, key: str, message: str, period: float | None = None) -> None:
        if self.due(key, period):
            self.logger().warning(message)

    def error(self, key: str, message: str, period: float | None = None) -> None:
        if self.due(key, period):
            self.logger().error(message)
