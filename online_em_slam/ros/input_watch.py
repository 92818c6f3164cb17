"""Which input streams are silent: the node's diagnostics and log name them.

Every subscribed stream is registered with its resolved topic and the parameter that
names it.  A stream that was heard is stale when nothing arrived for ``timeout``
seconds of wall time (steady clock: a stopped driver, not a paused bag clock, is what
this reports).  A stream never heard for ``timeout`` since it was subscribed is
``unheard``: with the others flowing, its topic name is the likely culprit (a
misspelled ``control_topic``).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Stream:
    key: str            # the topic as configured (what the callbacks report)
    topic: str          # resolved name
    parameter: str      # the parameter that names it
    required: bool      # odometry in motion_source control only places map -> odom


def publishers_text(count: int) -> str:
    return f"{count} publisher{'' if count == 1 else 's'}"


class InputWatch:
    def __init__(self) -> None:
        self._last: dict[str, float] = {}
        self._streams: dict[str, Stream] = {}
        self._since: float | None = None

    def expect(self, stream: Stream, now: float) -> None:
        """A subscribed stream; silent from ``now`` until heard."""
        self._streams[stream.key] = stream
        if self._since is None:
            self._since = now

    def heard(self, stream: str, now: float) -> None:
        self._last[stream] = now

    def topic(self, key: str) -> str:
        stream = self._streams.get(key)
        return stream.topic if stream is not None else key

    def stale(self, now: float, timeout: float) -> list[tuple[str, float]]:
        """(resolved topic, seconds since its last message) for every stream heard and then
        silent longer than ``timeout``."""
        return [(self.topic(name), now - last) for name, last in sorted(self._last.items()) if now - last > timeout]

    def unheard(self, now: float, timeout: float) -> list[Stream]:
        """The subscribed streams never heard, ``timeout`` after they were subscribed."""
        if self._since is None or now - self._since <= timeout:
            return []
        return [s for key, s in sorted(self._streams.items()) if key not in self._last]

    def any_heard(self) -> bool:
        return bool(self._last)

    def all_silent_for(self, now: float) -> float:
        """Seconds since the last message of any stream (0 while none was heard)."""
        return now - max(self._last.values()) if self._last else 0.0

    def clear(self, now: float | None = None) -> None:
        """Forget what was heard (the subscriptions stay expected, silent from ``now``)."""
        self._last.clear()
        if now is not None and self._streams:
            self._since = now
