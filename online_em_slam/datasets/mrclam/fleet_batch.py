"""The fleet batch over an MRCLAM fleet bag with the robots' reads of each other's barcodes.

    python -m online_em_slam.datasets.mrclam.fleet_batch BAG --params FILE --output DIR --robot-reads DATASET
                                                         [--read-gate G] [--noise-from RUN] [--match-gate M]

:mod:`online_em_slam.offline.fleet_batch` (the same options and outputs) with the reads as
bearing-range factors between the robots' poses (:mod:`online_em_slam.offline.robot_reads`).
The fleet bag does not carry them (``online-em-slam-convert mrclam --all-robots`` drops them,
counted), so ``DATASET`` is the dataset directory or archive the bag was converted from: its
reads are loaded (:func:`.dataset.load_robot_reads`) and stamped as the converter stamps the
bag's messages.  Here, not in offline/, because the offline layer reads no data set's files
(docs/ARCHITECTURE.md).
"""
from __future__ import annotations

import sys

import numpy as np

from ...offline import fleet_batch
from ...offline.robot_reads import FleetReads, fleet_reads, odometry_spans
from .convert import to_stamp_ns
from .dataset import load_robot_reads


def bag_stamps(times) -> np.ndarray:
    """Dataset seconds (n,) -> the stamps (n,) a reader of the bag sees for messages at those times
    (integer nanoseconds, then sec + nanosec 1e-9): a read's stamp equals its image's scan stamp."""
    ns = to_stamp_ns(times)
    return (ns // 10 ** 9).astype(np.float64) + (ns % 10 ** 9).astype(np.float64) * 1e-9


def mrclam_reads(dataset, inputs) -> FleetReads:
    """The reads of the MRCLAM ``dataset`` between the fleet bag's robots (``inputs``:
    :class:`online_em_slam.offline.fleet_runner.FleetInputs`), within their odometry's span in the bag;
    those the loader dropped are counted with those outside the bag."""
    numbers = [int(name[len("robot"):]) for name in inputs.names]
    reads = load_robot_reads(dataset, robots=numbers)
    fleet = fleet_reads(bag_stamps(reads.times), [f"robot{k}" for k in reads.observer],
                        [f"robot{k}" for k in reads.observed], np.column_stack([reads.range, reads.bearing]),
                        inputs.names, odometry_spans(inputs))
    fleet.not_in_the_bag.update({reason: n for reason, n in reads.drops.items() if n})
    return fleet


def main(argv=None) -> int:
    return fleet_batch.main(argv, reads_from=mrclam_reads,
                            prog="python -m online_em_slam.datasets.mrclam.fleet_batch")


if __name__ == "__main__":
    sys.exit(main())
