"""Read every message already waiting in a subscription's queue in one executor wake.

rclpy's single-threaded executor rebuilds its wait set for every message it
hands out (about 0.2-0.5 ms with the node's ~50 entities, more than a motion
input costs the estimator), so a node that falls behind a fast input stays
behind and its best-effort queue overflows: at 20x the Car Park bag's rate the
odometry and control queues did.  A callback made by :func:`draining` handles
its message and then takes those that queued up behind it directly from the
subscription (as the executor itself takes them), at most ``limit`` per wake so
that the other subscriptions, timers and services still get their turn, and
over a bounded stamp span (InputPipeline.read_ahead_span: none with the merge
off, where inputs are used in arrival order).
"""
from __future__ import annotations

from typing import Callable

from .conversions import stamp_to_sec

DRAIN_LIMIT = 64     # messages taken per wake beyond the one the executor handed out


def next_waiting(subscription):
    """The (message, MessageInfo) pair next in ``subscription``'s queue, None when it is empty
    (or the subscription is gone)."""
    if subscription is None:
        return None
    with subscription.handle:
        return subscription.handle.take_message(subscription.msg_type, subscription.raw)


def draining(handle: Callable, subscription: Callable, span: Callable[[], float],
             emptied: Callable[[], None], limit: int = DRAIN_LIMIT) -> Callable:
    """A subscription callback (message only, as every executor calls it) that calls
    ``handle(message, info)`` for its message (``info`` None: how long it waited is not known)
    and for those waiting behind it, with their MessageInfo, until one is stamped ``span()`` s
    after the first (0: none); ``emptied()`` when the queue was found empty (nothing waits: no
    lag).  ``subscription()`` returns the subscription (None once destroyed).

    The span bounds how far one stream is read ahead of the others in one wake: the executor
    then visits the other subscriptions, so the streams' newest stamps stay within about the
    span of each other, and the stamp guard, which judges a stream without a line of its own
    against the others' stamps, never sees a jump where there is only a queue read first."""
    def callback(msg) -> None:
        handle(msg, None)
        ahead = span()
        if ahead <= 0:
            return
        first = stamp_to_sec(msg.header.stamp)
        for _ in range(limit):
            taken = next_waiting(subscription())
            if taken is None:
                emptied()
                return
            handle(*taken)
            if stamp_to_sec(taken[0].header.stamp) - first >= ahead:
                return
    return callback
