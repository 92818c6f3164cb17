"""``online-em-slam-tf2-msgs``: build tf2_msgs (TFMessage only) into this environment, or check it.

    online-em-slam-tf2-msgs build [--install-requirements] [--force] [--prefix PREFIX]
    online-em-slam-tf2-msgs check      # exit 0 when tf2_msgs imports
    online-em-slam-tf2-msgs status     # where the sources are, what a build would lack

Also ``python -m online_em_slam.messages.tf2_build`` (and ``python -m online_em_slam.ros.tf``).
tf2_msgs is not on PyPI; after ``pip install "online_em_slam[ros]"`` the node and the bag
tools build it on first use (about 30 s, once), so this command is only needed to do it
ahead of time, to retry after a failure, or (``--install-requirements``) when the build
requirements are not installed (``make install`` uses it).  Progress and failure are one
line each; details in ``PREFIX/build/tf2_msgs.log``.  On a real Jazzy install tf2_msgs
comes from apt and nothing is built.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import build as builder
from . import first_use

PROG = "online-em-slam-tf2-msgs"


def status(prefix: Path) -> int:
    """Print where the sources are and whether a build could run here; 0 when nothing is missing."""
    reason = builder.missing(prefix)
    print(f"sources: {builder.SOURCE_DIR}")
    print(f"requirements: {builder.REQUIREMENTS_FILE} ({len(builder.requirements())} packages)")
    print(f"prefix: {prefix}")
    print(f"tf2_msgs: {'importable' if first_use.available() else 'not importable'}")
    print(f"build: {'possible' if reason is None else 'not possible: ' + reason}")
    return 0 if reason is None else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("build", "check", "status"),
                        help="build: build and install tf2_msgs; check: does tf2_msgs import; "
                             "status: sources and build prerequisites")
    parser.add_argument("--prefix", default=sys.prefix, help="install prefix (default: this environment)")
    parser.add_argument("--install-requirements", action="store_true",
                        help="pip install the build requirements first")
    parser.add_argument("--force", action="store_true", help="rebuild even when tf2_msgs imports")
    args = parser.parse_args(argv)
    prefix = Path(args.prefix).resolve()
    if args.command == "check":
        ok = first_use.available()
        print("tf2_msgs importable" if ok else f"tf2_msgs not importable ({PROG} build builds it)")
        return 0 if ok else 1
    if args.command == "status":
        return status(prefix)
    if not args.force and first_use.available():
        print("tf2_msgs: already importable: the node publishes map -> odom on /tf")
        return 0
    try:
        ok = first_use.ensure(prefix=prefix, retry=True, install_requirements=args.install_requirements,
                              force=args.force, log=lambda line: print(line, flush=True))
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
