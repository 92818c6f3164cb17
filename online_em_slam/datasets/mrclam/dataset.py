"""Loader for the UTIAS Multi-Robot Cooperative Localization and Mapping dataset (MRCLAM), numpy only.

Leung, Halpern, Barfoot, Liu, IJRR 30(8), 2011; the "synchronised 50 Hz" text form
(see /work/shared/datasets/mrclam/README.md).  One robot's run is read from

* ``Barcodes.dat`` (subject, barcode): subjects 1-5 are the robots, 6-20 the landmarks;
* ``Landmark_Groundtruth.dat`` (subject, x, y, sx, sy);
* ``RobotK_Odometry.dat`` (t, v, w): commanded forward (m/s) and angular (rad/s) velocity, 50 Hz;
* ``RobotK_Measurement.dat`` (t, barcode, range m, bearing rad);
* ``RobotK_Groundtruth.dat`` (t, x, y, yaw): Vicon pose, 50 Hz.

Times are seconds from the dataset start.  ``data_dir`` may be the directory holding the
.dat files, a directory holding exactly one ``MRCLAM_Dataset*`` directory, or a zip or tar
archive of one (``MRCLAM_Dataset1.zip``, ``MRCLAM_Dataset1.tar.xz``), read in memory (nothing is
extracted).

Messy input handled here:

* The files print times with 5 significant digits, so from t = 1000 s on the 50 Hz
  times are rounded to 0.1 s (1000.00, 1000.02 and 1000.04 all read 1000): runs of
  repeated times and 0.1 s jumps.  When a 50 Hz file's times are exactly that
  rounding of the grid ``t0 + 0.02 k``, the grid is used instead (rows counted in
  ``MrclamRun.retimed``); other files must have strictly increasing times.
  Measurement times have the same rounding and cannot be repaired (kept as read).
* Measurements are dropped and counted in ``MrclamRun.drops`` by the first reason
  that applies, in this order: ``before_odometry`` (no pose to hang them on; negative
  times in Dataset 9), ``after_odometry``, ``unknown_barcode`` (not in Barcodes.dat: a
  misread), ``other_robot`` (a barcode of subject 1-5: never a landmark),
  ``bad_range`` (non-finite or <= 0), ``bad_bearing`` (non-finite).
* Survey label errors: the surveyed landmarks' labels are checked against the
  measurements placed from the ground-truth poses and corrected where two entries are
  swapped (Dataset 1: subjects 11 and 17); ``MrclamRun.survey_relabelled``
  (:mod:`online_em_slam.datasets.mrclam.survey`).
* ``seconds``: only the first S seconds from the first odometry sample are kept of
  every stream (``start``: the S seconds from that many seconds after it, a later window
  of the same run); the rows cut are counted in ``MrclamRun.truncated`` (ground-truth rows
  outside the odometry's time span too), not as drops.

The robots' reads of each other's barcodes (``other_robot`` above) are read on their own by
:func:`load_robot_reads` (:class:`RobotReads`), for a fleet's batch (offline/robot_reads.py).
"""
from __future__ import annotations

import io
import math
import tarfile
import warnings
import zipfile
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .survey import relabelled_survey, survey_relabelling

ROBOTS = (1, 2, 3, 4, 5)
#: Odometry and ground truth are sampled at 50 Hz.
SAMPLE_PERIOD = 0.02
#: Significant digits of the times printed in the .dat files (see the module docstring).
PRINTED_DIGITS = 5
#: Why measurements are dropped, in the order the reasons are tested.
DROP_REASONS = ("before_odometry", "after_odometry", "unknown_barcode", "other_robot", "bad_range", "bad_bearing")
BARCODES, LANDMARKS = "Barcodes.dat", "Landmark_Groundtruth.dat"
DATASET_DIR_GLOB = "MRCLAM_Dataset*"


@dataclass(frozen=True)
class MrclamRun:
    """One robot's run: what the bag holds, as arrays (times in seconds of the dataset clock).

    Measurements are the kept ones only (sorted by time), ``measurement_subjects`` the
    landmark subject numbers (6-20) their barcodes map to.  ``drops``: measurements
    left out, by reason (DROP_REASONS); ``truncated``: rows cut by ``seconds`` (or ground
    truth outside the odometry span), per stream; ``retimed``: rows whose printed time
    was replaced by the 50 Hz grid, per stream.
    """

    robot: int
    source: str
    odometry_times: np.ndarray
    odometry_v: np.ndarray
    odometry_w: np.ndarray
    measurement_times: np.ndarray
    measurement_subjects: np.ndarray
    measurement_range: np.ndarray
    measurement_bearing: np.ndarray
    ground_truth_times: np.ndarray
    ground_truth_poses: np.ndarray          # (n, 3): x, y, yaw in the Vicon frame
    landmark_subjects: np.ndarray
    landmark_xy: np.ndarray                 # (m, 2)
    drops: Counter = field(default_factory=Counter)
    truncated: Counter = field(default_factory=Counter)
    retimed: Counter = field(default_factory=Counter)
    seconds: float | None = None
    start: float = 0.0                      # seconds after the first odometry sample where the run starts
    survey_relabelled: dict = field(default_factory=dict)   # {subject: survey entry it was listed under}

    @property
    def n_measurements(self) -> int:
        return len(self.measurement_times)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last odometry sample."""
        return float(self.odometry_times[-1] - self.odometry_times[0])


def robot_files(robot: int) -> dict[str, str]:
    """File names of one robot's streams: {"odometry": ..., "measurement": ..., "ground_truth": ...}."""
    return {"odometry": f"Robot{robot}_Odometry.dat", "measurement": f"Robot{robot}_Measurement.dat",
            "ground_truth": f"Robot{robot}_Groundtruth.dat"}


# --------------------------------------------------------------------------- reading the files

def _dataset_dir(path: Path) -> Path:
    """``path`` itself when it holds Barcodes.dat, else its one MRCLAM_Dataset* subdirectory."""
    if (path / BARCODES).is_file():
        return path
    subdirs = sorted(p for p in path.glob(DATASET_DIR_GLOB) if p.is_dir())
    if not subdirs:
        raise FileNotFoundError(f"{path}: no {BARCODES} and no {DATASET_DIR_GLOB} directory")
    if len(subdirs) > 1:
        raise ValueError(f"{path} holds {len(subdirs)} {DATASET_DIR_GLOB} directories "
                         f"({', '.join(p.name for p in subdirs)}); pass one of them")
    return subdirs[0]


def _read_directory(path: Path, names: list[str]) -> tuple[str, dict[str, str]]:
    base = _dataset_dir(path)
    texts = {}
    for name in names:
        if not (base / name).is_file():
            raise FileNotFoundError(f"{base / name} does not exist")
        texts[name] = (base / name).read_text(errors="replace")
    return str(base), texts


def _archive_members(path: Path):
    """(base name, a function reading the member's bytes) of every file in a zip archive (the
    form the dataset's site offers) or a tar archive (any compression), in archive order."""
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if not info.is_dir():
                    yield info.filename.rsplit("/", 1)[-1], lambda info=info: archive.read(info)
        return
    with tarfile.open(path, "r|*") as tar:              # one streaming pass
        for member in tar:
            if member.isfile():
                yield member.name.rsplit("/", 1)[-1], lambda member=member: tar.extractfile(member).read()


def _read_archive(path: Path, names: list[str]) -> tuple[str, dict[str, str]]:
    """The named members of a zip or tar archive (any directory inside), extracting nothing."""
    texts: dict[str, str] = {}
    try:
        for name, read in _archive_members(path):
            if name not in names:
                continue
            if name in texts:
                raise ValueError(f"{path} holds {name} more than once (several datasets?); extract one")
            texts[name] = read().decode(errors="replace")
    except (tarfile.TarError, zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{path}: not a readable zip or tar archive ({exc})") from None
    missing = [n for n in names if n not in texts]
    if missing:
        raise FileNotFoundError(f"{path}: archive holds no {missing[0]}")
    return str(path), texts


def read_texts(data_dir, names: list[str]) -> tuple[str, dict[str, str]]:
    """(source description, {name: text}) of the named .dat files of a directory or archive."""
    path = Path(data_dir).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    return _read_directory(path, names) if path.is_dir() else _read_archive(path, names)


def parse_table(name: str, text: str, columns: int) -> np.ndarray:
    """The whitespace-separated numbers of a .dat file as (rows, columns) float64; ``#`` starts a comment."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)          # "input contained no data"
            rows = np.loadtxt(io.StringIO(text), comments="#", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{name}: malformed: {' '.join(str(exc).split())}") from None
    if rows.size == 0:
        return np.zeros((0, columns))
    if rows.shape[1] != columns:
        raise ValueError(f"{name}: expected {columns} columns, got {rows.shape[1]}")
    return rows


def _require_finite(name: str, rows: np.ndarray) -> None:
    bad = ~np.isfinite(rows).all(axis=1)
    if bad.any():
        raise ValueError(f"{name}: non-finite value in data row {int(np.argmax(bad)) + 1}")


def _require_integers(name: str, values: np.ndarray) -> np.ndarray:
    bad = values != np.round(values)
    if bad.any():
        raise ValueError(f"{name}: non-integer subject or barcode {values[bad][0]!r}")
    return values.astype(np.int64)


# --------------------------------------------------------------------------- times

def printed_tolerance(times: np.ndarray, digits: int = PRINTED_DIGITS) -> np.ndarray:
    """Half a unit in the last place of ``times`` printed with ``digits`` significant digits."""
    magnitude = np.floor(np.log10(np.maximum(np.abs(times), 1e-12)))
    return 0.5 * 10.0 ** (magnitude - digits + 1) + 1e-9 * (1.0 + np.abs(times))


def regular_times(name: str, times: np.ndarray, period: float = SAMPLE_PERIOD) -> tuple[np.ndarray, np.ndarray]:
    """(times, mask of rows changed): the grid ``t0 + period k`` when ``times`` are its printed
    rounding (see the module docstring), else ``times`` unchanged when strictly increasing."""
    grid = times[0] + period * np.arange(len(times)) if len(times) else times
    if np.all(np.abs(times - grid) <= printed_tolerance(grid)):
        return grid, np.abs(times - grid) > 1e-9 * (1.0 + np.abs(grid))
    bad = np.diff(times) <= 0
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{name}: time does not increase at data row {i + 2} ({times[i + 1]:g} after {times[i]:g})")
    return times, np.zeros(len(times), dtype=bool)


def _time_window(t0: float, seconds: float | None) -> float:
    """End (exclusive) of the kept times; a hair below t0 + seconds so that t0 + S itself is cut."""
    return math.inf if seconds is None else t0 + seconds - 1e-9 * (1.0 + abs(t0 + seconds))


def _window_start(t0: float, start: float) -> float:
    """First kept time of a window ``start`` seconds after t0 (-inf for the run's own start, so
    that earlier measurements count as ``before_odometry``); a hair below t0 + start."""
    return -math.inf if start == 0 else t0 + start - 1e-9 * (1.0 + abs(t0 + start))


# --------------------------------------------------------------------------- streams

def _odometry(rows: np.ndarray, name: str, seconds: float | None, run: dict, start: float = 0.0) -> None:
    if len(rows) == 0:
        raise ValueError(f"{name}: no odometry samples")
    _require_finite(name, rows)
    times, changed = regular_times(name, rows[:, 0])
    t0 = times[0] + start
    keep = (times >= _window_start(times[0], start)) & (times < _time_window(t0, seconds))
    if not keep.any():
        raise ValueError(f"{name}: no odometry sample {start:g} s or more after the first ({times[0]:g} s); "
                         f"the run lasts {times[-1] - times[0]:g} s")
    run["retimed"]["odometry"] = int(np.count_nonzero(changed & keep))
    run["truncated"]["odometry"] = int(np.count_nonzero(~keep))
    run.update(odometry_times=times[keep], odometry_v=rows[keep, 1], odometry_w=rows[keep, 2])


def _ground_truth(rows: np.ndarray, name: str, run: dict) -> None:
    """Ground truth within the kept odometry span [first, last sample]."""
    _require_finite(name, rows)
    times, changed = regular_times(name, rows[:, 0])
    odo = run["odometry_times"]
    tol = 1e-9 * (1.0 + np.abs(times))
    keep = (times >= odo[0] - tol) & (times <= odo[-1] + tol)
    run["retimed"]["ground_truth"] = int(np.count_nonzero(changed & keep))
    run["truncated"]["ground_truth"] = int(np.count_nonzero(~keep))
    run.update(ground_truth_times=times[keep], ground_truth_poses=rows[keep, 1:4].copy())


def _barcode_subjects(barcodes: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Subject number of each measured barcode; 0 where Barcodes.dat does not list it."""
    order = np.argsort(table[:, 1])
    known, subjects = table[order, 1], table[order, 0]
    idx = np.searchsorted(known, barcodes).clip(0, len(known) - 1)
    return np.where(known[idx] == barcodes, subjects[idx], 0)


def _measurements(rows: np.ndarray, name: str, table: np.ndarray, seconds: float | None, run: dict,
                  start: float = 0.0) -> None:
    """Sort by time, cut to the window, drop by reason (DROP_REASONS order), keep the rest."""
    if not np.isfinite(rows[:, 0]).all():
        raise ValueError(f"{name}: non-finite time in data row {int(np.argmax(~np.isfinite(rows[:, 0]))) + 1}")
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    t, odo = rows[:, 0], run["odometry_times"]
    subjects = _barcode_subjects(rows[:, 1], table)
    cut = t >= _time_window(odo[0], seconds)
    if start > 0:               # before a later window: cut with the rest of the run, not a drop
        cut |= t < odo[0]
    run["truncated"]["measurements"] = int(np.count_nonzero(cut))
    with np.errstate(invalid="ignore"):
        checks = {"before_odometry": t < odo[0], "after_odometry": t > odo[-1], "unknown_barcode": subjects == 0,
                  "other_robot": np.isin(subjects, ROBOTS), "bad_range": ~(rows[:, 2] > 0) | ~np.isfinite(rows[:, 2]),
                  "bad_bearing": ~np.isfinite(rows[:, 3])}
    keep, drops = ~cut, Counter()
    for reason in DROP_REASONS:
        hit = keep & checks[reason]
        drops[reason] = int(np.count_nonzero(hit))
        keep &= ~hit
    run["drops"] = drops
    run.update(measurement_times=t[keep], measurement_subjects=subjects[keep], measurement_range=rows[keep, 2],
               measurement_bearing=rows[keep, 3])


def _check_arguments(robot, seconds, start: float = 0.0) -> None:
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or int(robot) not in ROBOTS:
        raise ValueError(f"robot must be one of 1-5, got {robot!r}")
    if seconds is not None and not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a positive number, got {seconds!r}")
    if isinstance(start, bool) or not (isinstance(start, (int, float)) and math.isfinite(start) and start >= 0):
        raise ValueError(f"start must be a number of seconds >= 0, got {start!r}")


def _read_run(source: str, texts: dict[str, str], robot: int, seconds: float | None, start: float) -> MrclamRun:
    """One robot's window of the files read (survey as listed)."""
    files = robot_files(robot)
    barcodes = parse_table(BARCODES, texts[BARCODES], 2)
    _require_finite(BARCODES, barcodes)
    if len(barcodes) == 0:
        raise ValueError(f"{BARCODES}: no barcodes")
    table = _require_integers(BARCODES, barcodes)
    landmarks = parse_table(LANDMARKS, texts[LANDMARKS], 5)
    _require_finite(LANDMARKS, landmarks)
    run: dict = {"retimed": Counter(), "truncated": Counter()}
    _odometry(parse_table(files["odometry"], texts[files["odometry"]], 3), files["odometry"], seconds, run, start)
    _ground_truth(parse_table(files["ground_truth"], texts[files["ground_truth"]], 4), files["ground_truth"], run)
    _measurements(parse_table(files["measurement"], texts[files["measurement"]], 4), files["measurement"], table,
                  seconds, run, start)
    return MrclamRun(robot=robot, source=source, landmark_subjects=_require_integers(LANDMARKS, landmarks[:, 0]),
                     landmark_xy=landmarks[:, 1:3].copy(), seconds=seconds, start=float(start), **run)


def load_mrclam(data_dir, robot: int, seconds: float | None = None, start: float = 0.0) -> MrclamRun:
    """Load robot ``robot`` (1-5) of the MRCLAM dataset at ``data_dir`` (directory or archive).

    ``seconds``: keep only the first S seconds from the first odometry sample, or from
    ``start`` seconds after it.  The survey's labels are checked against the run from its
    own start (a later window may see too few of a landmark).  Raises FileNotFoundError
    (missing file) or ValueError (malformed file, bad argument) with a one-line message
    naming the file.
    """
    _check_arguments(robot, seconds, start)
    source, texts = read_texts(data_dir, [BARCODES, LANDMARKS, *robot_files(int(robot)).values()])
    loaded = _read_run(source, texts, int(robot), seconds, start)
    moves = survey_relabelling(loaded if start == 0 else _read_run(source, texts, int(robot), None, 0.0))
    if not moves:
        return loaded
    return replace(loaded, landmark_subjects=relabelled_survey(loaded.landmark_subjects, moves),
                   survey_relabelled=moves)


# --------------------------------------------------------------------------- robot-to-robot reads

#: Why robot-to-robot reads are left out, in the order the reasons are tested.
READ_DROP_REASONS = ("before_odometry", "after_odometry", "own_barcode", "bad_range", "bad_bearing")


@dataclass(frozen=True)
class RobotReads:
    """The robots' reads of each other's barcodes, n of them sorted by time then observer.

    ``times`` (n,) s of the dataset clock; ``observer`` (n,) the reading robot, ``observed`` (n,)
    the robot read (subjects 1-5); ``range`` (n,) m and ``bearing`` (n,) rad as the landmark
    reads.  ``drops``: reads left out, by reason (READ_DROP_REASONS); ``truncated``: reads cut
    by ``seconds``.
    """

    source: str
    times: np.ndarray
    observer: np.ndarray
    observed: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    drops: Counter = field(default_factory=Counter)
    truncated: int = 0

    def __len__(self) -> int:
        return len(self.times)


def _reads_of(robot: int, rows: np.ndarray, name: str, table: np.ndarray, odometry: np.ndarray,
              seconds: float | None, drops: Counter) -> tuple[np.ndarray, int]:
    """The kept robot reads of one Measurement file as (k, 5) rows: time, observer, observed,
    range, bearing; and how many ``seconds`` cut.  The landmark measurements' window and checks."""
    if not np.isfinite(rows[:, 0]).all():
        raise ValueError(f"{name}: non-finite time in data row {int(np.argmax(~np.isfinite(rows[:, 0]))) + 1}")
    subjects = _barcode_subjects(rows[:, 1], table)
    rows, subjects = rows[np.isin(subjects, ROBOTS)], subjects[np.isin(subjects, ROBOTS)]
    t = rows[:, 0]
    keep = t < _time_window(odometry[0], seconds)
    truncated = int(np.count_nonzero(~keep))
    with np.errstate(invalid="ignore"):
        checks = {"before_odometry": t < odometry[0], "after_odometry": t > odometry[-1],
                  "own_barcode": subjects == robot, "bad_range": ~(rows[:, 2] > 0) | ~np.isfinite(rows[:, 2]),
                  "bad_bearing": ~np.isfinite(rows[:, 3])}
    for reason in READ_DROP_REASONS:
        hit = keep & checks[reason]
        drops[reason] += int(np.count_nonzero(hit))
        keep &= ~hit
    kept = np.column_stack([t, np.full(len(t), robot), subjects, rows[:, 2], rows[:, 3]])[keep]
    return kept, truncated


def load_robot_reads(data_dir, robots=ROBOTS, seconds: float | None = None) -> RobotReads:
    """The robot-to-robot barcode reads of ``robots`` (observers, 1-5) at ``data_dir`` (directory
    or archive), each robot's within its odometry span and first ``seconds`` as :func:`load_mrclam`
    keeps its landmark measurements."""
    for robot in robots:
        _check_arguments(robot, seconds)
    names = [BARCODES] + [robot_files(int(r))[s] for r in robots for s in ("odometry", "measurement")]
    source, texts = read_texts(data_dir, names)
    barcodes = parse_table(BARCODES, texts[BARCODES], 2)
    _require_finite(BARCODES, barcodes)
    table = _require_integers(BARCODES, barcodes)
    drops, truncated, parts = Counter({r: 0 for r in READ_DROP_REASONS}), 0, [np.zeros((0, 5))]
    for robot in map(int, robots):
        files, window = robot_files(robot), {"retimed": Counter(), "truncated": Counter()}
        _odometry(parse_table(files["odometry"], texts[files["odometry"]], 3), files["odometry"], seconds, window)
        kept, cut = _reads_of(robot, parse_table(files["measurement"], texts[files["measurement"]], 4),
                              files["measurement"], table, window["odometry_times"], seconds, drops)
        parts.append(kept)
        truncated += cut
    rows = np.concatenate(parts)
    rows = rows[np.lexsort((rows[:, 1], rows[:, 0]))]
    return RobotReads(source, rows[:, 0], rows[:, 1].astype(np.int64), rows[:, 2].astype(np.int64),
                      rows[:, 3], rows[:, 4], drops, truncated)
