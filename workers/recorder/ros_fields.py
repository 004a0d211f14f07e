"""A deserialised ROS message (a ``rosbags`` message object) as plain JSON.

- nested messages become objects, field by field;
- arrays of bytes (``uint8[]``, ``int8[]``: images, point clouds, occupancy data) become
  ``{"_base64": "...", "length": n}``: a third of the size of a list of numbers;
- other numeric arrays become lists;
- floats that JSON cannot hold (NaN, infinities) become the strings ``"nan"``, ``"inf"``, ``"-inf"``.

A message whose JSON would be over the recording's message size limit keeps every array of more
than :data:`LARGE_ARRAY` elements described instead, ``{"_truncated": true, "length": n,
"sha256": "..."}``, so the rest of the message (its header, its sizes, its encoding) is kept.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.ros import BYTES_KEY, described, to_blobs

LARGE_ARRAY = 1024
"""Elements above which an array is described instead of kept, in a message over the size limit."""
_BYTE_KINDS = {"u1", "i1"}


def plain(value: Any, cap: int | None = None) -> Any:
    """``value`` as JSON-able Python; arrays of more than ``cap`` elements only described."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: plain(getattr(value, f.name), cap)
            for f in dataclasses.fields(value)
            if not f.name.startswith("__")  # rosbags keeps the type name as __msgtype__
        }
    if isinstance(value, float):
        return value if math.isfinite(value) else _non_finite(value)
    if value is None or isinstance(value, (str, int, bool)):
        return value
    if isinstance(value, (bytes, bytearray, memoryview)):
        return _bytes(bytes(value), cap)
    if hasattr(value, "dtype") and hasattr(value, "tolist"):  # numpy arrays and scalars
        return _array(value, cap)
    if isinstance(value, (list, tuple)):
        if cap is not None and len(value) > cap:
            return described(json.dumps([plain(v) for v in value]).encode(), len(value))
        return [plain(v, cap) for v in value]
    return str(value)


def _non_finite(value: float) -> str:
    return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")


def _bytes(data: bytes, cap: int | None) -> dict[str, Any]:
    if cap is not None and len(data) > cap:
        return described(data, len(data))
    return {BYTES_KEY: base64.b64encode(data).decode(), "length": len(data)}


def _array(array: Any, cap: int | None) -> Any:
    if getattr(array, "ndim", 0) == 0:
        return plain(array.item())
    if array.dtype.str[1:] in _BYTE_KINDS:
        return _bytes(array.tobytes(), cap)
    if cap is not None and array.size > cap:
        return described(array.tobytes(), int(array.size))
    return [plain(v) for v in array.tolist()] if array.dtype.kind == "f" else array.tolist()


def message_fields(
    message: Any, max_bytes: int, blob_max: int = 0
) -> tuple[dict[str, Any], bool, dict[str, bytes]]:
    """The message's fields as plain JSON, whether large arrays had to be left out to keep its
    JSON within ``max_bytes``, and the blobs: byte arrays over :data:`BLOB_FROM` and up to
    ``blob_max`` bytes (0: none) are kept whole apart, named in the fields by their SHA-256."""
    blobs: dict[str, bytes] = {}
    fields = to_blobs(plain(message), blobs, blob_max) if blob_max else plain(message)
    if len(json.dumps(fields, separators=(",", ":"))) <= max_bytes:
        return fields, False, blobs
    return plain(message, LARGE_ARRAY), True, {}


def header_stamp(fields: dict[str, Any]) -> datetime | None:
    """``header.stamp`` (ROS 1 and ROS 2 both name it ``sec`` and ``nanosec`` in ``rosbags``)."""
    header = fields.get("header")
    stamp = header.get("stamp") if isinstance(header, dict) else None
    if not isinstance(stamp, dict) or not isinstance(stamp.get("sec"), int):
        return None
    nanos = stamp.get("nanosec", stamp.get("nsec", 0))
    return nanos_to_datetime(stamp["sec"] * 1_000_000_000 + (nanos if isinstance(nanos, int) else 0))


def nanos_to_datetime(nanos: int) -> datetime:
    """A time in nanoseconds since the epoch, in UTC to the microsecond (what ``datetime`` holds)."""
    seconds, rest = divmod(nanos, 1_000_000_000)
    return datetime.fromtimestamp(seconds, timezone.utc).replace(microsecond=rest // 1000)
