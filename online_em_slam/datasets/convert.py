"""``online-em-slam-convert DATASET OUTPUT``: a KTH data set (car_park, victoria_park), one
robot of UTIAS MRCLAM, or all five (``--all-robots``: one bag, a namespace per robot) as a
ROS 2 bag the node and ``online-em-slam run`` consume."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .kth.convert import STREAM_BUILDERS, convert, dir_size
from .mrclam.convert import run_cli
from .mrclam.fleet_convert import run_fleet_cli


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="online-em-slam-convert",
        description="Convert a KTH SLAM dataset (ACFR ute) or UTIAS MRCLAM (one robot, or all) to a ROS 2 bag.")
    parser.add_argument("dataset", choices=sorted(STREAM_BUILDERS) + ["mrclam"])
    parser.add_argument("output", help="bag directory to create")
    parser.add_argument("--data-dir", default=None,
                        help="directory holding car_park/ and victoria_park/ (default: packaged data, "
                             "or $ONLINE_EM_SLAM_DATA); mrclam: the MRCLAM_DatasetN directory or its .zip or .tar.xz")
    parser.add_argument("--robot", type=int, default=None, help="mrclam only (required): robot 1-5")
    parser.add_argument("--all-robots", action="store_true",
                        help="mrclam only: all five robots in one bag, topics under /robot1 .. /robot5")
    parser.add_argument("--seconds", type=float, default=None,
                        help="mrclam only: keep the first S seconds of every stream")
    parser.add_argument("--start", type=float, default=0.0,
                        help="mrclam, one robot: the window starts S seconds after the run's first odometry "
                             "sample (with --seconds, a later window of the run; default 0)")
    parser.add_argument("--unknown-ids", action="store_true",
                        help="mrclam only: observation ids -1 (unknown) instead of the landmark numbers")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing bag directory")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--no-map-to-gps", action="store_true",
                        help="leave out the static map -> gps transform (for a node started at the "
                             "GPS-derived initial pose, whose map frame is the gps frame)")
    args = parser.parse_args(argv)
    if args.dataset == "mrclam":
        return run_fleet_cli(args) if args.all_robots else run_cli(args)
    if args.robot is not None or args.seconds is not None or args.start or args.unknown_ids or args.all_robots:
        print("online-em-slam-convert: error: --robot, --all-robots, --seconds, --start and --unknown-ids are for "
              "mrclam only",
              file=sys.stderr)
        return 1
    t0 = time.monotonic()
    try:
        counts = convert(args.dataset, args.output, args.data_dir, args.storage,
                         progress=not args.no_progress, overwrite=args.overwrite,
                         map_to_gps=not args.no_map_to_gps)
    except (FileNotFoundError, FileExistsError, ValueError) as exc:
        print(f"online-em-slam-convert: error: {exc}", file=sys.stderr)
        return 1
    elapsed = time.monotonic() - t0
    for topic, n in counts.items():
        print(f"{topic:28s} {n:8d}")
    print(f"wrote {sum(counts.values())} messages to {args.output} "
          f"({dir_size(Path(args.output)) / 1e6:.1f} MB, {args.storage}) in {elapsed:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
