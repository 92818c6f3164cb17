"""Which input streams have gone silent: the node's diagnostics turn WARN for them.

A stream counts once it has been heard; it is stale when nothing arrived for
``timeout`` seconds of wall time (steady clock: a stopped driver, not a paused bag
clock, is what this reports).
"""
from __future__ import annotations


class InputWatch:
    def __init__(self) -> None:
        self._last: dict[str, float] = {}

    def heard(self, stream: str, now: float) -> None:
        self._last[stream] = now

    def stale(self, now: float, timeout: float) -> list[tuple[str, float]]:
        """(stream, seconds since its last message) for every stream silent longer than ``timeout``."""
        return [(name, now - last) for name, last in sorted(self._last.items()) if now - last > timeout]

    def clear(self) -> None:
        self._last.clear()
