"""ROS messages back in their native encoding, for the files ROS tools read (MCAP for Foxglove,
ROS 1 bags): ROS 1 serialisation with the message definition (``ros1msg``), or CDR with a ROS 2
definition (``ros2msg``).

The recording keeps a ROS message's fields as JSON (:mod:`ros_fields`), and the definition of its
type once, as a ``ros_schema`` record (:data:`fleetbus.schemas.ros.ROS_SCHEMA_TYPE`): the text a
ROS 1 bag's connection header or a live publisher sent (``message_definition``), or the one
``rosbags`` generates for a ROS 2 bag's type. Each ``ros`` record names its schema by key. A
:class:`Codec` builds the type from that text with ``rosbags`` and serialises the fields again:
the bytes a ROS node would have sent.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from fleetbus.schemas.ros import (
    BLOB_KEY,
    BYTES_KEY,
    ROS_EXCHANGE,
    ROS_SCHEMA_TYPE,
    TRUNCATED_KEY,
    ros_routing_key,
    schema_key,
)
from fleetbus.workers.store.recordings import RecordedMessage

ROS1, ROS2 = "ros1msg", "ros2msg"
"""Schema encodings, as MCAP names them."""
MESSAGE_ENCODINGS = {ROS1: "ros1", ROS2: "cdr"}
"""The message encoding of each schema encoding, as MCAP names them."""
#: The numpy type of each ROS base type of an array (``rosbags`` holds such arrays as numpy's).
_NUMPY = {
    **{name: name for name in ("bool", "int8", "uint8", "int16", "uint16", "int32", "uint32")},
    **{name: name for name in ("int64", "uint64", "float32", "float64")},
    "byte": "uint8",
    "char": "uint8",
}
_FLOATS = {"float32", "float64"}


class NotEncodable(ValueError):
    """Fields that cannot be serialised again (an array kept only as a description, a field the
    definition does not have); the message says which."""


@dataclass(frozen=True)
class RosSchema:
    """The definition of one ROS type, as recorded once and named by its key."""

    ros_type: str
    """``pkg/msg/Type``."""
    encoding: str
    """:data:`ROS1` or :data:`ROS2`."""
    definition: str
    md5sum: str | None = None
    """ROS 1's hash of the definition (what a bag's connection and ``rosbag info`` name)."""

    @property
    def key(self) -> str:
        return schema_key(self.encoding, self.ros_type, self.definition)

    @property
    def ros1_type(self) -> str:
        """``pkg/Type``, how ROS 1 names it."""
        return self.ros_type.replace("/msg/", "/")

    @property
    def message_encoding(self) -> str:
        return MESSAGE_ENCODINGS[self.encoding]

    def document(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "ros_type": self.ros_type,
            "encoding": self.encoding,
            "definition": self.definition,
            "md5sum": self.md5sum,
        }

    @classmethod
    def of(cls, document: Any) -> RosSchema | None:
        """The schema of a ``ros_schema`` record's document; None for one that is not."""
        try:
            schema = cls(
                str(document["ros_type"]),
                str(document["encoding"]),
                str(document["definition"]),
                document.get("md5sum"),
            )
        except (KeyError, TypeError):
            return None
        return schema if schema.encoding in MESSAGE_ENCODINGS else None


def schema_record(schema: RosSchema, robot: str, topic: str, at: datetime) -> RecordedMessage:
    """The ``ros_schema`` record of ``schema``, first seen on ``robot``'s ``topic`` at ``at``."""
    document = schema.document()
    return RecordedMessage(
        key=schema.key,
        type=ROS_SCHEMA_TYPE,
        recorded_at=at,
        exchange=ROS_EXCHANGE,
        routing_key=ros_routing_key(robot, topic),
        user_id=None,
        robot_id=robot,
        known=True,
        document=document,
        properties={"type": schema.ros_type},
        size=len(schema.definition),
    )


class Codec:
    """Serialises the fields of one ROS type, as its definition says (``rosbags``' typestore)."""

    def __init__(self, schema: RosSchema) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.schema = schema
        self.store = get_typestore(Stores.EMPTY)
        try:
            self.store.register(get_types_from_msg(schema.definition, schema.ros_type))
        except Exception as error:  # rosbags' parser raises its own kinds
            raise NotEncodable(f"the definition of {schema.ros_type} cannot be read: {error}") from None

    def serialize(self, fields: dict[str, Any]) -> bytes:
        """The message in its own encoding (ROS 1, or CDR for a ROS 2 type)."""
        if self.schema.encoding == ROS1:
            return self.serialize_ros1(fields)
        message = self.build(self.schema.ros_type, fields)
        return bytes(self.store.serialize_cdr(message, self.schema.ros_type))

    def serialize_ros1(self, fields: dict[str, Any]) -> bytes:
        """The message as ROS 1 serialises it (a ROS 2 type's too, for a ROS 1 bag)."""
        message = self.build(self.schema.ros_type, fields)
        return bytes(self.store.serialize_ros1(message, self.schema.ros_type))

    def ros1_definition(self) -> tuple[str, str]:
        """The ROS 1 definition and its MD5: the recorded ones for a ROS 1 type, else written by
        ``rosbags`` from the type."""
        if self.schema.encoding == ROS1 and self.schema.md5sum:
            return self.schema.definition, self.schema.md5sum
        text, md5sum = self.store.generate_msgdef(self.schema.ros_type, ros_version=1)
        return str(text), str(md5sum)

    def build(self, type_name: str, document: Any) -> Any:
        """A ``rosbags`` message of ``type_name`` from its fields as JSON."""
        if not isinstance(document, dict):
            raise NotEncodable(f"{type_name}: expected an object, got {type(document).__name__}")
        _, fields = self.store.fielddefs[type_name]
        values = {name: self._value(node, document.get(name), f"{type_name}.{name}") for name, node in fields}
        return self.store.types[type_name](**values)

    def _value(self, node: Any, value: Any, where: str) -> Any:
        kind, detail = node
        if kind.name == "BASE":
            return _base(detail[0], value, where)
        if kind.name == "NAME":
            return self.build(detail, value if value is not None else {})
        sub, _ = detail
        if isinstance(value, dict) and value.get(TRUNCATED_KEY):
            raise NotEncodable(f"{where}: only described in the recording ({value.get('length')} elements)")
        if isinstance(value, dict) and BLOB_KEY in value:
            raise NotEncodable(f"{where}: its bytes ({value[BLOB_KEY]}) are not in the blob store")
        if sub[0].name == "BASE" and sub[1][0] in _NUMPY:
            import numpy as np  # only where messages are serialised again: the recorder needs none

            dtype = _NUMPY[sub[1][0]]
            if isinstance(value, dict) and BYTES_KEY in value:
                return np.frombuffer(base64.b64decode(value[BYTES_KEY]), dtype=dtype).copy()
            items = [_base(sub[1][0], v, where) for v in (value or [])]
            return np.array(items, dtype=dtype)
        return [self._value(sub, item, where) for item in (value or [])]


async def with_blobs(
    record: RecordedMessage, get_blob: Callable[[str], Awaitable[bytes | None]]
) -> RecordedMessage:
    """``record`` with the byte arrays it keeps in the blob store read back into its fields (as
    ``{"_base64"}``), so that it can be serialised again; one whose bytes are gone stays named."""

    async def inline(value: Any) -> Any:
        if isinstance(value, list):
            return [await inline(item) for item in value]
        if not isinstance(value, dict):
            return value
        if BLOB_KEY in value:
            data = await get_blob(str(value[BLOB_KEY]))
            if data is not None:
                return {BYTES_KEY: base64.b64encode(data).decode(), "length": len(data)}
            return value
        return {key: await inline(item) for key, item in value.items()}

    document = record.document
    if not isinstance(document, dict) or BLOB_KEY not in json.dumps(document.get("fields")):
        return record
    return replace(record, document={**document, "fields": await inline(document.get("fields"))})


def _base(kind: str, value: Any, where: str) -> Any:
    if kind == "string":
        return "" if value is None else str(value)
    if kind in _FLOATS:
        if isinstance(value, str):
            return {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}[value]
        return float(value or 0.0)
    if kind == "bool":
        return bool(value)
    if isinstance(value, (int, float)) or value is None:
        return int(value or 0)
    raise NotEncodable(f"{where}: {value!r} is no {kind}")
