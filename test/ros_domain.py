"""ROS domain ids no other process on this host holds, so concurrent test runs (two
checkouts, a CI run beside a developer's) never see each other's topics: LOCALHOST
discovery isolates domains, not processes (docs in ../shared/docs/ROS.md).

A claim is an exclusive lock on a file named after the id in the temporary directory,
held until the process exits; ids that are free in DDS's port scheme only."""
from __future__ import annotations

import fcntl
import os
import tempfile

USABLE = tuple(range(1, 102)) + tuple(range(215, 233))
_held: list = []          # the open lock files: closing one would free its id


def claim() -> int:
    """A domain id no other process on this host has claimed (RuntimeError when none is left)."""
    first = os.getpid() % len(USABLE)
    for k in range(len(USABLE)):
        domain = USABLE[(first + k) % len(USABLE)]
        lock = open(os.path.join(tempfile.gettempdir(), f"online_em_slam_ros_domain_{domain}.lock"), "w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _held.append(lock)
        return domain
    raise RuntimeError(f"every ROS domain id in {USABLE[0]}..{USABLE[-1]} is claimed on this host")
