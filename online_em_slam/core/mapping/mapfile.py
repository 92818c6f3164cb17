"""Map files of :meth:`OnlineEMSlam.save_map` / ``load_map``: atomic writes, validated reads.

A map file is an ``.npz`` archive holding the landmark parameter theta and the
EM bookkeeping needed to continue estimation (one row per landmark), the pose
at save time and a format version.  :func:`read_map` checks everything (array
headers before any data is read, then shapes, types and values) and raises
:class:`MapFileError` (a ValueError) with one line naming the file and the
problem, so that a caller can validate completely *before* touching its state.
:func:`write_map` never leaves a half-written file under the target name: it
writes to an unpredictable temporary name in the same directory, fsyncs it,
renames it over the target and fsyncs the directory.

The helpers :func:`write_file_atomic` (any bytes, e.g. ``metrics.json``) and
:func:`confined_path` (a user-supplied file name kept inside one directory)
serve the tools and the ROS node.
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import tempfile
import zipfile
from typing import Callable

import numpy as np

FORMAT_VERSION = 1
# Width of a landmark's stored statistics: the complete-data statistics (A00, A01, A11, b0, b1)
# of em/statistics.py, in which every M-step's ``saved_arrays`` writes its landmarks' information
# and estimates (A, A theta): either M-step loads a file the other wrote.
STATS_WIDTH = 5
# Refuse files claiming more rows than this before reading their data: a header can
# declare any shape, and the data would be allocated first and checked later.
MAX_LANDMARKS = 1_000_000

# name -> (shape of one row, kind): "float" finite reals, "count" integers >= 0,
# "id" distinct integers >= 0, "flag" booleans (or 0/1).
ROW_FIELDS = {
    "theta": ((2,), "float"),
    "ids": ((), "id"),
    "count": ((), "count"),
    "inv_n": ((), "float"),
    "n_obs": ((), "count"),
    "confirmed": ((), "flag"),
    "stats": ((STATS_WIDTH,), "float"),
    "spread": ((2, 2), "float"),
    "avg_stats": ((STATS_WIDTH,), "float"),
    "avg_count": ((), "count"),
}
_OTHER_FIELDS = {"version": (), "pose": (3,)}
# Optional: the noise in use when learned online (core/em/noise/learner.py), restored on load:
# noise = (sigma_range, range_growth, sigma_bearing, rho, motion_scale), noise_mixture =
# (mixture weights, mixture scales) as a (2, C) array, with Student-t noise
# noise_dof (), its degrees of freedom, noise_serial (2,), the serial correlation
# of range and bearing errors (absent: 0), and noise_serial_length (2,), its decay with the
# viewpoint's change (absent: 0, none).
_NOISE_FIELDS = ("noise", "noise_mixture")
_DOF_FIELD = "noise_dof"
_SERIAL_FIELD = "noise_serial"
_SERIAL_LENGTH_FIELD = "noise_serial_length"
MAX_MIXTURE_COMPONENTS = 16
_NUMERIC = {"float": "biuf", "count": "biu", "id": "iu", "flag": "biu"}
_KIND_TEXT = {"float": "numbers", "count": "integers", "id": "integer ids", "flag": "booleans"}


class MapFileError(ValueError):
    """A map file cannot be used; the message names the file and the reason."""


# ----------------------------------------------------------------- atomic writes
def _temporary_prefix(path: str) -> str:
    return f".{os.path.basename(path)}.{os.getpid()}."


def _remove_stale_temporaries(path: str) -> None:
    """Remove temporary files of ``path`` left by writers that died (kill -9, power loss).

    Temporary names carry the writer's pid; a file whose writer is still alive
    may be in use and stays.
    """
    directory, base = os.path.split(path)
    pattern = re.compile(rf"\.{re.escape(base)}\.(\d+)\.[^/]+\.tmp")
    with contextlib.suppress(OSError):
        for name in os.listdir(directory or "."):
            match = pattern.fullmatch(name)
            if match and not _process_alive(int(match.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(directory, name))


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False       # our own leftovers: no write of ours is in progress on this name
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True        # exists, owned by someone else
    return True


def _fsync_directory(directory: str) -> None:
    # The rename is durable only once the directory entry is on disk.
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_file_atomic(path, write: Callable[[io.BufferedWriter], None]) -> None:
    """Write ``path`` through ``write(handle)`` atomically.

    The temporary file is created exclusively with an unpredictable name
    (mkstemp: no symlink planted under a guessable ``path.tmp`` is followed),
    flushed and fsynced before it replaces ``path``; the rename replaces a
    symlink at ``path`` instead of writing through it.  On any failure the
    temporary file is removed and ``path`` is untouched.
    """
    path = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(path)
    _remove_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=_temporary_prefix(path), suffix=".tmp")
    try:
        # mkstemp creates 0600; keep the mode an existing file had, else the usual 0644.
        with contextlib.suppress(OSError):
            os.fchmod(fd, os.lstat(path).st_mode & 0o777 if os.path.isfile(path) else 0o644)
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_directory(directory)


def write_bytes_atomic(path, data: bytes) -> None:
    write_file_atomic(path, lambda handle: handle.write(data))


# ----------------------------------------------------------------- validation
def _check_row_field(name: str, value: np.ndarray, m: int) -> np.ndarray:
    row_shape, kind = ROW_FIELDS[name]
    if value.shape != (m,) + row_shape:
        expected = "(" + ", ".join(["M"] + [str(d) for d in row_shape]) + ("," if not row_shape else "") + ")"
        raise MapFileError(f"{name} has shape {value.shape}, expected {expected} with M = {m} landmarks")
    if value.dtype.kind not in _NUMERIC[kind]:
        raise MapFileError(f"{name} has type {value.dtype}, expected {_KIND_TEXT[kind]}")
    if kind == "float":
        value = value.astype(float)
        if not np.all(np.isfinite(value)):
            raise MapFileError(f"{name} holds non-finite values")
        return value
    if kind == "flag":
        if np.any((value != 0) & (value != 1)):
            raise MapFileError(f"{name} holds values other than 0 and 1")
        return value.astype(bool)
    if m and value.min() < 0:
        raise MapFileError(f"{name} holds negative values")
    if m and value.max() > np.iinfo(np.int64).max:
        raise MapFileError(f"{name} holds values of 2^63 or more")
    value = value.astype(np.int64)
    if kind == "id" and np.unique(value).size != m:
        raise MapFileError(f"{name} holds repeated landmark ids")
    return value


def _check_pose(value: np.ndarray) -> np.ndarray:
    if value.shape != (3,) or value.dtype.kind not in "iuf":
        raise MapFileError(f"pose has shape {value.shape} and type {value.dtype}, expected 3 numbers (x, y, yaw)")
    value = value.astype(float)
    if not np.all(np.isfinite(value)):
        raise MapFileError(f"pose {value.tolist()} is not finite")
    return value


def _check_version(value: np.ndarray) -> None:
    if value.shape != () or value.dtype.kind not in "iu" or int(value) != FORMAT_VERSION:
        raise MapFileError(f"map format version {value.tolist()!r}, expected {FORMAT_VERSION}")


def _check_noise(noise: np.ndarray, mixture: np.ndarray) -> dict[str, np.ndarray]:
    """Learned noise values: stds > 0, growth >= 0, |rho| < sigma_r sigma_b, scale > 0,
    mixture weights summing to 1 and scales > 0."""
    if noise.shape != (5,) or noise.dtype.kind not in "iuf" or mixture.dtype.kind not in "iuf":
        raise MapFileError(f"noise has shape {noise.shape} and type {noise.dtype}, expected 5 numbers")
    if mixture.ndim != 2 or mixture.shape[0] != 2 or not 1 <= mixture.shape[1] <= MAX_MIXTURE_COMPONENTS:
        raise MapFileError(f"noise_mixture has shape {mixture.shape}, expected (2, C) with "
                           f"1 <= C <= {MAX_MIXTURE_COMPONENTS}")
    noise, mixture = noise.astype(float), mixture.astype(float)
    if not (np.all(np.isfinite(noise)) and np.all(np.isfinite(mixture))):
        raise MapFileError("noise holds non-finite values")
    sigma_r, growth, sigma_b, rho, scale = noise
    if min(sigma_r, sigma_b, scale) <= 0 or growth < 0 or abs(rho) >= sigma_r * sigma_b:
        raise MapFileError(f"noise {noise.tolist()} is not a valid (sigma_range > 0, range_growth >= 0, "
                           f"sigma_bearing > 0, |rho| < sigma_range sigma_bearing, motion_scale > 0)")
    weights, scales = mixture
    if np.any(weights < 0) or abs(weights.sum() - 1.0) > 1e-6 or np.any(scales <= 0):
        raise MapFileError(f"noise_mixture {mixture.tolist()}: weights must be >= 0 and sum to 1, scales > 0")
    return {"noise": noise, "noise_mixture": mixture}


def check_map(arrays: dict, max_landmarks: int = MAX_LANDMARKS) -> dict[str, np.ndarray]:
    """Validated copy of a map's arrays (every field of ROW_FIELDS, ``pose``, ``version``,
    and the learned noise when present)."""
    missing = [name for name in (*ROW_FIELDS, *_OTHER_FIELDS) if name not in arrays]
    if missing:
        raise MapFileError(f"missing array(s): {', '.join(missing)}")
    values = {name: np.asarray(arrays[name]) for name in (*ROW_FIELDS, *_OTHER_FIELDS)}
    _check_version(values["version"])
    theta = values["theta"]
    m = theta.shape[0] if theta.ndim >= 1 else -1
    if m < 0 or m > max_landmarks:
        raise MapFileError(f"theta has shape {theta.shape}, expected (M, 2) with M <= {max_landmarks}")
    checked = {name: _check_row_field(name, values[name], m) for name in ROW_FIELDS}
    checked["pose"] = _check_pose(values["pose"])
    checked["version"] = np.array(FORMAT_VERSION)
    present = [name for name in _NOISE_FIELDS if name in arrays]
    if present and len(present) != len(_NOISE_FIELDS):
        raise MapFileError(f"{present[0]} without {[n for n in _NOISE_FIELDS if n not in present][0]}")
    if present:
        checked.update(_check_noise(np.asarray(arrays["noise"]), np.asarray(arrays["noise_mixture"])))
    if _DOF_FIELD in arrays:
        if not present:
            raise MapFileError(f"{_DOF_FIELD} without noise")
        checked[_DOF_FIELD] = _check_dof(np.asarray(arrays[_DOF_FIELD]))
    if _SERIAL_FIELD in arrays:
        if not present:
            raise MapFileError(f"{_SERIAL_FIELD} without noise")
        checked[_SERIAL_FIELD] = _check_serial(np.asarray(arrays[_SERIAL_FIELD]))
    if _SERIAL_LENGTH_FIELD in arrays:
        if not present:
            raise MapFileError(f"{_SERIAL_LENGTH_FIELD} without noise")
        checked[_SERIAL_LENGTH_FIELD] = _check_serial_length(np.asarray(arrays[_SERIAL_LENGTH_FIELD]))
    return checked


def _check_serial_length(length: np.ndarray) -> np.ndarray:
    """The serial correlation's decay lengths of range and bearing: two numbers in [0, 1000] m."""
    if length.shape != (2,) or length.dtype.kind not in "iuf" or not np.all((length >= 0) & (length <= 1e3)):
        raise MapFileError(f"{_SERIAL_LENGTH_FIELD} = {length.tolist()} must be two numbers in [0, 1000]")
    return length.astype(float)


def _check_serial(serial: np.ndarray) -> np.ndarray:
    """The serial correlation of range and bearing errors: two numbers in [0, 0.99]."""
    if serial.shape != (2,) or serial.dtype.kind not in "iuf" or not np.all((serial >= 0) & (serial <= 0.99)):
        raise MapFileError(f"{_SERIAL_FIELD} = {serial.tolist()} must be two numbers in [0, 0.99]")
    return serial.astype(float)


def _check_dof(dof: np.ndarray) -> np.ndarray:
    """The Student-t degrees of freedom: one finite number > 0."""
    if dof.shape != () or dof.dtype.kind not in "iuf" or not np.isfinite(dof) or dof <= 0:
        raise MapFileError(f"{_DOF_FIELD} = {dof.tolist()} must be one finite number > 0")
    return dof.astype(float)


# ----------------------------------------------------------------- files
def write_map(path, arrays: dict) -> None:
    """Validate ``arrays`` (``version`` is added) and write them atomically to ``path``.

    Validating first means a corrupt in-memory estimate never replaces a good file.
    """
    data = check_map({**arrays, "version": np.array(FORMAT_VERSION)})
    write_file_atomic(path, lambda handle: np.savez(handle, **data))


def _expected_shape(name: str, m: int | None) -> tuple | None:
    if name in _NOISE_FIELDS or name in (_DOF_FIELD, _SERIAL_FIELD, _SERIAL_LENGTH_FIELD):
        return {"noise": (5,), _DOF_FIELD: (), _SERIAL_FIELD: (2,), _SERIAL_LENGTH_FIELD: (2,)}.get(name)
    if name in _OTHER_FIELDS:
        return _OTHER_FIELDS[name]
    return None if m is None else (m,) + ROW_FIELDS[name][0]


def _read_member(archive: zipfile.ZipFile, name: str, m: int | None, max_landmarks: int) -> np.ndarray:
    """One array, its header checked before its data is allocated."""
    member = f"{name}.npy"
    with archive.open(member) as stream:
        version = np.lib.format.read_magic(stream)
        read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                       else np.lib.format.read_array_header_2_0)
        shape, _, dtype = read_header(stream)
    if dtype.hasobject:
        raise MapFileError(f"{name} holds Python objects")
    if len(shape) > 1 and name == "noise_mixture" and shape[1] > MAX_MIXTURE_COMPONENTS:
        raise MapFileError(f"noise_mixture has {shape[1]} components, more than {MAX_MIXTURE_COMPONENTS}")
    if shape and shape[0] > max_landmarks:
        raise MapFileError(f"{name} has {shape[0]} rows, more than the limit of {max_landmarks} landmarks")
    expected = _expected_shape(name, m)
    if expected is not None and shape != expected:
        origin = f" (M = {m} landmarks from theta)" if name in ROW_FIELDS else ""
        raise MapFileError(f"{name} has shape {shape}, expected {expected}{origin}")
    with archive.open(member) as stream:
        return np.lib.format.read_array(stream, allow_pickle=False)


def _read_arrays(path: str, max_landmarks: int) -> dict[str, np.ndarray]:
    with zipfile.ZipFile(path) as archive:
        present = {info.filename.removesuffix(".npy") for info in archive.infolist()}
        missing = [name for name in (*ROW_FIELDS, *_OTHER_FIELDS) if name not in present]
        if missing:
            raise MapFileError(f"missing array(s): {', '.join(missing)}")
        arrays = {"version": _read_member(archive, "version", None, max_landmarks)}
        _check_version(arrays["version"])      # a file of another version: say so, not "wrong shape"
        arrays["theta"] = _read_member(archive, "theta", None, max_landmarks)
        if arrays["theta"].ndim != 2 or arrays["theta"].shape[1] != 2:     # M comes from theta: check it first
            raise MapFileError(f"theta has shape {arrays['theta'].shape}, expected (M, 2)")
        m = arrays["theta"].shape[0]
        for name in (*ROW_FIELDS, "pose", *(n for n in (*_NOISE_FIELDS, _DOF_FIELD, _SERIAL_FIELD, _SERIAL_LENGTH_FIELD)
                                            if n in present)):
            if name not in arrays:
                arrays[name] = _read_member(archive, name, m, max_landmarks)
        return arrays


def read_map(path, max_landmarks: int = MAX_LANDMARKS) -> dict[str, np.ndarray]:
    """The validated arrays of the map file ``path`` (see :func:`check_map`).

    Raises MapFileError (one line, naming ``path``) for a file that cannot be
    opened, is not a map archive, is truncated or holds inconsistent arrays.
    """
    path = os.fspath(path)
    try:
        return check_map(_read_arrays(path, max_landmarks), max_landmarks)
    except MapFileError as error:
        raise MapFileError(f"{path}: {error}") from None
    except zipfile.BadZipFile as error:
        raise MapFileError(f"{path}: not a complete .npz map archive (truncated, corrupt or another "
                           f"kind of file): {error}") from None
    except OSError as error:
        raise MapFileError(f"{path}: cannot read: {error.strerror or error}") from None
    except Exception as error:  # noqa: BLE001 - numpy/zipfile raise many kinds on corrupt data
        raise MapFileError(f"{path}: corrupt map file: {type(error).__name__}: {error}") from None


# ----------------------------------------------------------------- confinement
def map_file_path(map_file: str, map_directory: str = "") -> tuple[str, str]:
    """(file name, directory) of the node's map_file / map_directory parameters, for :func:`confined_path`.

    Without a map directory the map file's own directory is the one (relative to the
    working directory), and the file name is its base name: joining the whole relative
    path again would put ``dir/sub/m.npz`` at ``dir/sub/dir/sub/m.npz``.
    """
    if map_directory.strip():
        return map_file, os.path.abspath(os.path.expanduser(map_directory.strip()))
    path = os.path.expanduser(map_file.strip())
    return os.path.basename(path), os.path.abspath(os.path.dirname(path) or ".")


def confined_path(file_name: str, directory: str) -> str:
    """Absolute path of ``file_name`` inside ``directory``, or MapFileError.

    ``file_name`` may be relative (to ``directory``) or absolute; ``..`` is
    refused outright, and after resolving symlinks the file (and any existing
    parent) must still lie inside the resolved ``directory``: a symlink in the
    directory cannot send a write or a read elsewhere.
    """
    raw = os.path.expanduser(file_name.strip())
    if not raw:
        raise MapFileError("map file name is empty")
    if ".." in re.split(r"[/\\]", raw):
        raise MapFileError(f"{file_name!r}: '..' is not allowed in the map file name")
    root = os.path.realpath(os.path.expanduser(directory))
    candidate = os.path.normpath(os.path.join(root, raw))
    resolved = os.path.realpath(candidate)
    if os.path.commonpath([root, resolved]) != root or resolved == root:
        raise MapFileError(f"{file_name!r} resolves to {resolved}, outside the map directory {root}")
    return resolved
