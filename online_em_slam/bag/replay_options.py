"""Playback options of ``online-em-slam-replay`` that follow ``ros2 bag play``.

    --loop                    play the bag again and again (the clock jumps back at each pass,
                              as with ros2 bag play --loop: the node resets on it)
    --start-offset S          start S seconds into the bag; the latched messages before that
                              point (/tf_static, ground-truth map) are still published first
    --playback-duration S     stop S seconds of bag time after the start
    --remap OLD:=NEW ...      publish topic OLD as NEW
    --exclude T ...           leave these topics out (--exclude-regex R: those matching R)
    --clock [HZ]              publish rosgraph_msgs/Clock on /clock: with HZ, at that wall rate
                              (ros2 bag play --clock HZ); without, before every message
    --start-paused            wait until the ~/resume service (std_srvs/Trigger) is called;
                              ~/pause and ~/toggle_paused pause again while playing

Not implemented from ros2 bag play: keyboard controls, ``--delay`` (use
``--start-delay``), ``--qos-profile-overrides-path``, ``--topics`` by regex, and
the rosbag2_interfaces services (their message package is not in the wheels:
the std_srvs/Trigger services above stand in for them).

:func:`messages` replaces ``reader.messages()`` in the replay loop: it selects
the time window, paces the messages to the wall clock (``--rate``), handles pause,
loop and /clock itself (it sets ``args.rate`` to 0 so that the loop's own
pacing, which knows nothing of pauses and loops, stays off).
"""
from __future__ import annotations

import argparse
import re
import threading
import time


class ClockAction(argparse.Action):
    """``--clock`` alone: a /clock message before every message; ``--clock HZ``: at HZ."""

    def __call__(self, parser, namespace, values, option_string=None):
        hz = 0.0 if values is None else float(values)
        if hz < 0:
            parser.error("--clock HZ must be positive")
        namespace.clock_hz = hz
        namespace.clock = False          # the replay loop's own /clock stays off: messages() publishes it


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.set_defaults(clock=False, clock_hz=None)
    parser.add_argument("--clock", nargs="?", metavar="HZ", action=ClockAction,
                        help="publish /clock: at HZ (wall rate), or before every message without HZ")
    parser.add_argument("--loop", action="store_true", help="play the bag in a loop (until Ctrl-C)")
    parser.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                        help="start S seconds into the bag (latched messages before it are still sent)")
    parser.add_argument("--playback-duration", type=float, default=0.0, metavar="S",
                        help="play S seconds of bag time (0: to the end)")
    parser.add_argument("--remap", nargs="+", default=[], metavar="OLD:=NEW", type=_remap_spec,
                        help="publish OLD as NEW")
    parser.add_argument("--exclude", nargs="+", default=[], metavar="TOPIC", help="topics to leave out")
    parser.add_argument("--exclude-regex", default=None, metavar="REGEX", help="leave out topics matching REGEX")
    parser.add_argument("--start-paused", action="store_true",
                        help="start paused; the ~/resume service (std_srvs/Trigger) starts playback")


def _remap_spec(spec: str) -> str:
    parse_remaps([spec])                 # argparse turns the error into a usage message
    return spec


def parse_remaps(specs) -> dict[str, str]:
    out = {}
    for spec in specs or ():
        old, sep, new = spec.partition(":=")
        if not sep or not old or not new:
            raise argparse.ArgumentTypeError(f"--remap expects OLD:=NEW, got {spec!r}")
        out["/" + old.lstrip("/")] = "/" + new.lstrip("/")
    return out


def remap(args, topic: str) -> str:
    """The topic name to publish ``topic`` on."""
    return parse_remaps(getattr(args, "remap", ())).get(topic, topic)


def selected(args, topic: str) -> bool:
    """False for topics left out by --exclude / --exclude-regex."""
    if topic in {"/" + t.lstrip("/") for t in getattr(args, "exclude", ())}:
        return False
    pattern = getattr(args, "exclude_regex", None)
    return not (pattern and re.search(pattern, topic))


class Player:
    """Wall-clock pacing of bag time with pause, and the bag time for /clock."""

    def __init__(self, rate: float, paused: bool = False) -> None:
        self.rate = rate
        self.paused = paused
        self._lock = threading.Lock()
        self._ref_bag = self._ref_wall = None    # bag time shown at a wall time (None: not started)
        self._last_ns = 0

    def start_pass(self, first_ns: int) -> None:
        with self._lock:
            self._ref_bag, self._ref_wall = first_ns, time.monotonic()

    def set_paused(self, paused: bool) -> None:
        with self._lock:
            if paused != self.paused and self._ref_bag is not None and self.rate > 0:
                # Freeze or restart the bag clock where it stands.
                self._ref_bag, self._ref_wall = self._now_locked(), time.monotonic()
            self.paused = paused

    def _now_locked(self) -> int:
        if self._ref_bag is None or self.rate <= 0:
            return self._last_ns                 # no pacing: the last message's time
        if self.paused:
            return self._ref_bag                 # frozen by set_paused / start_pass
        return int(self._ref_bag + (time.monotonic() - self._ref_wall) * 1e9 * self.rate)

    def now_ns(self) -> int:
        with self._lock:
            return self._now_locked()

    def wait_for(self, log_ns: int, stop: threading.Event | None = None) -> None:
        """Sleep until ``log_ns`` is due (never while paused)."""
        while True:
            with self._lock:
                due = None if self.paused else (
                    time.monotonic() if self.rate <= 0 else
                    self._ref_wall + (log_ns - self._ref_bag) * 1e-9 / self.rate)
            delay = 0.05 if due is None else due - time.monotonic()
            if delay <= 0:
                with self._lock:
                    self._last_ns = log_ns
                return
            time.sleep(min(delay, 0.05))


def _passes(args, reader, conns):
    """Yield (first pass?, message iterator) per pass over the selected window."""
    start = reader.start_time + int(round(max(args.start_offset, 0.0) * 1e9))
    stop = start + int(round(args.playback_duration * 1e9)) if args.playback_duration > 0 else None
    first = True
    while True:
        yield first, reader.messages(connections=conns, start=start, stop=stop)
        first = False
        if not args.loop:
            return


def _latched_before(reader, conns, start_ns: int):
    """The latched topics' messages before ``start_ns`` (sent first with --start-offset)."""
    from .bagio import is_latched

    latched = [c for c in conns if is_latched(c) or c.topic == "/tf_static"]
    if not latched or start_ns <= reader.start_time:
        return []
    return list(reader.messages(connections=latched, stop=start_ns))


def _clock_publisher(node):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def publish(ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(ns), 1_000_000_000)
        pub.publish(msg)
    return publish


def _clock_thread(publish, player: Player, hz: float, stop: threading.Event) -> threading.Thread:
    def run() -> None:
        while not stop.wait(1.0 / hz):
            if player.now_ns() > 0:
                publish(player.now_ns())
    thread = threading.Thread(target=run, name="replay-clock", daemon=True)
    thread.start()
    return thread


def _services(node, player: Player, log):
    """~/resume, ~/pause, ~/toggle_paused served by an executor in a background thread."""
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    def handler(paused):
        def serve(request, response):
            player.set_paused(not player.paused if paused is None else paused)
            response.success, response.message = True, "paused" if player.paused else "playing"
            log(f"replay: {response.message}")
            return response
        return serve

    for name, paused in (("~/resume", False), ("~/pause", True), ("~/toggle_paused", None)):
        node.create_service(Trigger, name, handler(paused))
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    thread = threading.Thread(target=_spin_quietly, args=(executor,), name="replay-services", daemon=True)
    thread.start()
    return executor, thread


def _spin_quietly(executor) -> None:
    try:
        executor.spin()
    except Exception:  # noqa: BLE001 - shutdown races end the thread, never the replay
        pass


def messages(args, reader, conns, node, log=lambda text: None):
    """(conn, log_time, raw) for the replay loop, paced and with the options applied."""
    if not conns:
        return
    player = Player(args.rate, paused=bool(getattr(args, "start_paused", False)))
    # The pacing is done here (pause, loop and offset included): the caller's loop must not
    # wait again on its own schedule, which knows nothing of them.
    args.rate = 0.0
    hz = getattr(args, "clock_hz", None)
    publish_clock = _clock_publisher(node) if hz is not None else None
    stop = threading.Event()
    clock = _clock_thread(publish_clock, player, hz, stop) if hz else None
    services = _services(node, player, log) if player.paused else None
    if player.paused:
        log(f"replay: paused; call the {node.get_fully_qualified_name()}/resume service (std_srvs/Trigger)")
    try:
        start = reader.start_time + int(round(max(args.start_offset, 0.0) * 1e9))
        for conn, log_time, raw in _latched_before(reader, conns, start):
            yield conn, log_time, raw
        for _, iterator in _passes(args, reader, conns):
            started = False
            for conn, log_time, raw in iterator:
                if not started:
                    player.start_pass(log_time)
                    started = True
                player.wait_for(log_time)
                if publish_clock is not None and not hz:
                    publish_clock(log_time)      # --clock without HZ: before every message
                yield conn, log_time, raw
    finally:
        stop.set()
        if clock is not None:
            clock.join(timeout=1.0)
        if services is not None:
            services[0].shutdown(timeout_sec=1.0)
            services[1].join(timeout=1.0)
