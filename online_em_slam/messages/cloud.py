"""PointCloud2 codec with numpy only (no ROS import): the one decoder and the one builder.

sensor_msgs_py is not available everywhere (not on PyPI), and the same layout
is written by the bag converter (rosbags messages) and read and written by the
node (rclpy messages), so the byte-level work lives here once.  Message objects
of either library are handled through their common attribute names; the
builder takes the library's PointCloud2 and PointField classes.

:func:`observations_from_message` is the one reader of observation clouds (node
and offline runner): it refuses and counts bad fields, ids and values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..core.models.angles import wrap_angle
from ..core.types import Observations

# sensor_msgs/PointField datatype constants.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
_NUMPY_OF = {INT8: "i1", UINT8: "u1", INT16: "i2", UINT16: "u2", INT32: "i4",
             UINT32: "u4", FLOAT32: "f4", FLOAT64: "f8"}
_DATATYPE_OF = {np.dtype(v).str[1:]: k for k, v in _NUMPY_OF.items()}

# Layout of the landmark observations the node consumes (docs/NODE.md, "Inputs").
OBSERVATION_FIELDS = (("x", "f4"), ("y", "f4"), ("z", "f4"), ("range", "f4"),
                      ("bearing", "f4"), ("id", "i4"), ("range_std", "f4"), ("bearing_std", "f4"))
# Layout of the landmark map the node publishes.
LANDMARK_FIELDS = (("x", "f4"), ("y", "f4"), ("z", "f4"), ("id", "i4"), ("cov_xx", "f4"),
                   ("cov_xy", "f4"), ("cov_yy", "f4"), ("n_obs", "i4"))


class CloudFormatError(ValueError):
    """The cloud's fields or sizes do not describe its data."""


@dataclass(frozen=True)
class FieldSpec:
    name: str
    offset: int
    datatype: int
    count: int = 1


def encode(columns: dict[str, np.ndarray], layout=None) -> tuple[list[FieldSpec], int, bytes]:
    """Pack equal-length columns into PointCloud2 fields, point_step and data bytes.

    ``layout`` is a sequence of (name, numpy type) giving order and types;
    by default the columns' own order and dtypes are used (little-endian).
    """
    layout = layout or [(k, np.asarray(v).dtype.str[1:]) for k, v in columns.items()]
    dtype = np.dtype([(name, "<" + typ) for name, typ in layout])
    lengths = {len(np.atleast_1d(columns[name])) for name, _ in layout if name in columns}
    if len(lengths) > 1:
        raise CloudFormatError(f"columns have different lengths: {sorted(lengths)}")
    n = lengths.pop() if lengths else 0
    packed = np.zeros(n, dtype=dtype)
    for name, _ in layout:
        if name in columns:
            packed[name] = np.atleast_1d(columns[name])
    specs = [FieldSpec(name, dtype.fields[name][1], _DATATYPE_OF[np.dtype(typ).str[1:]])
             for name, typ in layout]
    return specs, dtype.itemsize, packed.tobytes()


def decode(fields, point_step: int, width: int, height: int, row_step: int,
           data, is_bigendian: bool = False, required=()) -> dict[str, np.ndarray]:
    """Unpack a PointCloud2 payload into columns, validating every size.

    ``fields`` are objects with name/offset/datatype/count (PointField of rclpy
    or rosbags, or FieldSpec).  Raises CloudFormatError with the reason when a
    required field is missing or sizes disagree, instead of reading garbage.
    """
    n = int(width) * int(height)
    buf = bytes(data) if not isinstance(data, (bytes, bytearray)) else data
    if point_step <= 0 and n > 0:
        raise CloudFormatError(f"point_step {point_step} must be positive")
    if n > 0 and len(buf) < n * point_step:
        raise CloudFormatError(f"data holds {len(buf)} bytes, {n} points x point_step {point_step} need {n * point_step}")
    if height > 1 and row_step != width * point_step:
        raise CloudFormatError(f"row_step {row_step} != width {width} x point_step {point_step}")
    names, formats, offsets = [], [], []
    order = ">" if is_bigendian else "<"
    for f in fields:
        if f.datatype not in _NUMPY_OF:
            raise CloudFormatError(f"field {f.name!r} has unknown datatype {f.datatype}")
        if int(getattr(f, "count", 1) or 1) != 1:
            continue
        size = np.dtype(_NUMPY_OF[f.datatype]).itemsize
        if f.offset < 0 or f.offset + size > point_step:
            raise CloudFormatError(f"field {f.name!r} at offset {f.offset} does not fit point_step {point_step}")
        names.append(f.name)
        formats.append(order + _NUMPY_OF[f.datatype])
        offsets.append(f.offset)
    missing = [name for name in required if name not in names]
    if missing:
        raise CloudFormatError(f"missing field(s): {', '.join(missing)}")
    if n == 0:
        return {name: np.zeros(0, dtype=np.dtype(fmt).newbyteorder("=")) for name, fmt in zip(names, formats)}
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    if height > 1:
        rows = np.frombuffer(buf, dtype=np.uint8, count=height * row_step).reshape(height, row_step)
        raw = rows[:, : width * point_step].reshape(-1).tobytes()
    else:
        raw = buf[: n * point_step]
    arr = np.frombuffer(raw, dtype=dtype, count=n)
    return {name: arr[name].astype(arr[name].dtype.newbyteorder("="), copy=True) for name in names}


def decode_message(msg, required=()) -> dict[str, np.ndarray]:
    """decode() for a PointCloud2 message object of rclpy or rosbags."""
    return decode(msg.fields, msg.point_step, msg.width, msg.height, msg.row_step,
                  msg.data, bool(msg.is_bigendian), required)


# ----------------------------------------------------------------- building

@lru_cache(maxsize=32)
def _fields(field_type, specs: tuple) -> tuple:
    # Field objects are the same for every message of a layout; building them
    # once per layout saves a fifth of the bag conversion time.
    return tuple(field_type(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in specs)


def build_message(cloud_type, field_type, header, columns: dict, layout=None, raw_data: bool = False):
    """A height-1 PointCloud2 of ``cloud_type`` (rclpy or rosbags class) from columns.

    ``layout`` as for :func:`encode`.  ``raw_data``: data as a numpy uint8
    array (rosbags serialises that) instead of bytes (rclpy).
    """
    specs, step, data = encode(columns, layout)
    n = len(data) // step if step else 0
    payload = np.frombuffer(data, dtype=np.uint8).copy() if raw_data else data
    return cloud_type(header=header, height=1, width=n, fields=list(_fields(field_type, tuple(specs))),
                      is_bigendian=False, point_step=step, row_step=step * n, data=payload, is_dense=True)


# ----------------------------------------------------------------- observations
FLOAT_FIELDS = ("range", "bearing", "range_std", "bearing_std")
MAX_ID = 2 ** 31 - 1          # ids are published as int32 (map cloud, Marker.id)
# Bearings beyond one extra turn are not a sensor's angle convention ([0, 2 pi) or
# (-pi, pi]) but garbage; wrapping 1e20 rad would give an arbitrary direction.
MAX_ABS_BEARING = 2.0 * math.pi


def _float_column(columns: dict, name: str) -> np.ndarray | None:
    """A measurement column; integer types are refused: a UINT8 ``range`` is not metres."""
    if name not in columns:
        return None
    column = columns[name]
    if column.dtype.kind != "f":
        raise CloudFormatError(f"field {name!r} has integer type {column.dtype}; "
                               f"{', '.join(FLOAT_FIELDS)} must be FLOAT32 or FLOAT64")
    return column.astype(float)


def _ids_column(columns: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """ids as int64 and a mask of valid ones: -1 (unknown) or an integer in [0, MAX_ID].

    A float id field holding NaN, 1e20 or 2.5, an id >= 2^31 (it would be published
    negative and collide with another marker) or below -1 is invalid, not unknown:
    associating such an observation by likelihood would hide a broken publisher.
    """
    if "id" not in columns:
        return np.full(n, -1, dtype=np.int64), np.ones(n, dtype=bool)
    raw = columns["id"]
    if raw.dtype.kind not in "iuf":
        raise CloudFormatError(f"field 'id' has type {raw.dtype}")
    values = raw.astype(float) if raw.dtype.kind == "f" else raw.astype(np.int64).astype(float)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values == np.round(values)) & (values >= -1) & (values <= MAX_ID)
    ids = np.where(valid, values, -1).astype(np.int64)
    return ids, valid


def _count(drops, reason: str, mask: np.ndarray) -> None:
    if drops is not None and mask.any():
        drops[reason] += int(mask.sum())


def observations_from_message(msg, drops=None) -> Observations:
    """Observations from a PointCloud2 with fields range, bearing [, id, range_std, bearing_std].

    Raises CloudFormatError for missing fields, inconsistent sizes or measurement
    fields of integer type.  Observations with an invalid id (see _ids_column), a
    zero range or a bearing beyond +-2 pi are left out and counted in ``drops``
    (a Counter, by reason: invalid_id, zero_range, bearing_out_of_range).  Other
    values are passed on (the core drops and counts non-finite and negative
    ranges); bearings are wrapped to (-pi, pi].  When observations were left
    out, the result carries their number as ``refused_points``: a cloud left
    empty by them is counted under those reasons only, not as ``empty_cloud``.
    """
    columns = decode_message(msg, required=("range", "bearing"))
    ranges, bearings = _float_column(columns, "range"), _float_column(columns, "bearing")
    std = {name: _float_column(columns, name) for name in ("range_std", "bearing_std")}
    ids, valid_id = _ids_column(columns, ranges.shape[0])
    finite = np.isfinite(bearings)
    with np.errstate(invalid="ignore"):
        wild = finite & (np.abs(bearings) > MAX_ABS_BEARING)
    zero = ranges == 0.0
    _count(drops, "invalid_id", ~valid_id)
    _count(drops, "zero_range", valid_id & zero)
    _count(drops, "bearing_out_of_range", valid_id & ~zero & wild)
    keep = valid_id & ~zero & ~wild
    bearings = np.where(finite, wrap_angle(np.where(finite & keep, bearings, 0.0)), bearings)
    observations = Observations(ranges, bearings, ids, std["range_std"], std["bearing_std"])
    if keep.all():
        return observations
    observations = observations.subset(keep)
    # A cloud emptied by these refusals is counted under them, not once more as an empty cloud.
    observations.refused_points = int((~keep).sum())
    return observations
