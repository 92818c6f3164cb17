"""PointCloud2 payload codec with numpy only (no ROS import).

sensor_msgs_py is not available everywhere (not on PyPI), and the same layout
is written by the bag converter (rosbags messages) and read and written by the
node (rclpy messages), so the byte-level work lives here once.  Message objects
of either library are handled through their common attribute names.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# sensor_msgs/PointField datatype constants.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
_NUMPY_OF = {INT8: "i1", UINT8: "u1", INT16: "i2", UINT16: "u2", INT32: "i4",
             UINT32: "u4", FLOAT32: "f4", FLOAT64: "f8"}
_DATATYPE_OF = {np.dtype(v).str[1:]: k for k, v in _NUMPY_OF.items()}

# Layout of the landmark observations the node consumes (see README).
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
