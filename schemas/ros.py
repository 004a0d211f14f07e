"""How a ROS message is named in the recording, written down once.

Every ROS message the recording holds, whether imported from a bag (``fleetbus import``) or
recorded live, is one record of type :data:`ROS_TYPE` with:

=============  ==================================================================
field          value
=============  ==================================================================
type           ``ros`` (one table or collection for every ROS message type)
exchange       ``ros`` (:data:`ROS_EXCHANGE`)
routing key    ``<robot>.ros.<topic>``, the topic's ``/`` as ``.``
               (``explorer1.ros.camera.image_raw``; :func:`ros_routing_key`)
robot          the robot the messages belong to
recorded_at    the ROS log time (a bag's receive time), to the microsecond
sent_at        ``header.stamp`` when the message has one, else None
document       a :class:`RosMessage`: topic, ROS type, log time in ns, stamp, fields
               as plain JSON
=============  ==================================================================

:func:`fleetbus.workers.recorder.ros_records.ros_record` builds such a record from a
:class:`RosMessage`. Field values are plain JSON; a byte array is kept as base64 under
:data:`BYTES_KEY`, or, over the size cap, only described under :data:`TRUNCATED_KEY`.
"""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Iterator, Sequence
from typing import Any

from pydantic import AwareDatetime, BaseModel, Field

from fleetbus.schemas.bodies import INT64_MAX

ROS_TYPE = "ros"
"""The recording type (table or collection) of every ROS message."""
ROS_TF_TYPE = "ros_tf"
"""The recording type of each transform of a TF message, one record per transform, to query by
frame (``fleetbus.workers.recorder.ros_tf``); a copy of what the ``ros`` records hold."""
ROS_SCHEMA_TYPE = "ros_schema"
"""The recording type of the definitions of ROS types, one record per definition, named by the
``schema`` of the messages (``fleetbus.workers.recorder.ros_native``)."""
ROS_EXCHANGE = "ros"
"""The exchange a recorded ROS message names: none on the bus, it marks the ROS origin."""
ROUTING_SEGMENT = "ros"
# ROS field names start with a letter, so these keys cannot be a message's own; and MongoDB
# stores them as they are (it refuses or mangles keys that start with "$").
BYTES_KEY = "_base64"
"""A byte array (``uint8[]``) is kept as ``{"_base64": "...", "length": n}``."""
TRUNCATED_KEY = "_truncated"
"""A byte array over the size cap is kept as ``{"_truncated": true, "length": n, "sha256": "..."}``."""
BLOB_KEY = "_blob"
"""A large byte array kept whole in the recording's blob store: ``{"_blob": "<sha256>", "length": n}``."""
RAW_KEY = "_raw"
"""A byte array that travels beside its document, not in it (the live bridge's pipe):
``{"_raw": i, "length": n}`` names the ``i``-th that follows; once read, ``{"_raw": b"...",
"length": n}`` holds it (in memory only: :func:`to_blobs` moves it to a blob)."""
BLOB_FROM = 64 * 1024
"""Bytes above which a byte array is kept apart, in the recording's blob store (a bag import), or
travels apart as ``ros_chunk`` events (the live bridge) on its way there."""


class RosDefinition(BaseModel):
    """A ROS type's definition, as its publisher sent it (carried by a connection's first message)."""

    encoding: str = Field(description="``ros1msg`` (ROS 1 message definition) or ``ros2msg``.")
    text: str = Field(description="The definition with its dependencies, as a connection header holds it.")
    md5sum: str | None = Field(default=None, description="ROS 1's MD5 of the definition.")


class RosMessage(BaseModel):
    """The stored document of one ROS message."""

    topic: str = Field(description="The ROS topic, as in the bag (``/camera/image_raw``).")
    ros_type: str = Field(
        description="The ROS message type as the bag names it: ``sensor_msgs/msg/Image`` (ROS 2) or "
        "``sensor_msgs/Image`` (ROS 1)."
    )
    log_time_ns: int = Field(
        ge=0,
        le=INT64_MAX,
        description="The ROS log time in nanoseconds (``recorded_at`` holds it to the microsecond).",
    )
    stamp: AwareDatetime | None = Field(
        default=None, description="``header.stamp``, when the message has one."
    )
    fields: dict[str, Any] = Field(description="The message's fields as plain JSON.")
    schema_key: str | None = Field(
        default=None,
        description="The key of the ``ros_schema`` record of its type's definition, when known.",
    )
    definition: RosDefinition | None = Field(
        default=None,
        description="The definition itself, on the first message of a live connection (the recorder "
        "keeps it as a ``ros_schema`` record).",
    )


MESSAGE_FIELDS = frozenset(RosMessage.model_fields)
"""The top-level fields of a ROS message's document; a query names any other as ``fields.<name>``."""


def schema_key(encoding: str, ros_type: str, definition: str) -> str:
    """The key of a ROS type's definition in the recording (a message's ``schema_key``)."""
    return hashlib.sha256(f"{encoding}\0{ros_type}\0{definition}".encode()).hexdigest()[:32]


def topic_segments(topic: str) -> str:
    """``/camera/image_raw`` as ``camera.image_raw`` (a ROS name has no dots, so this is reversible)."""
    return ".".join(part for part in topic.split("/") if part) or "_"


def ros_routing_key(robot: str, topic: str) -> str:
    """The routing key a ROS message of ``robot`` on ``topic`` is recorded under."""
    return f"{robot}.{ROUTING_SEGMENT}.{topic_segments(topic)}"


def topic_of(routing_key: str) -> str | None:
    """The ROS topic a recorded routing key names, or None when it is not a ROS one."""
    parts = routing_key.split(".", 2)
    if len(parts) < 3 or parts[1] != ROUTING_SEGMENT:
        return None
    return "/" + parts[2].replace(".", "/")


def ros_record_key(source: str, index: int) -> str:
    """The recording key of the ``index``-th message of ``source`` (a bag's content hash, or a live
    session's id): the same message imported twice is stored once."""
    digest = hashlib.sha256(f"ros\0{source}\0{index}".encode()).hexdigest()
    return digest[:32]


def described(data: bytes, length: int) -> dict[str, Any]:
    """An array kept only described: its length and the SHA-256 of its bytes."""
    return {TRUNCATED_KEY: True, "length": length, "sha256": hashlib.sha256(data).hexdigest()}


def to_blobs(value: Any, blobs: dict[str, bytes], blob_max: int) -> Any:
    """``value`` (fields as plain JSON) with its large byte arrays (``{"_base64"}`` over
    :data:`BLOB_FROM`, and every ``{"_raw"}``) moved to ``blobs``: up to ``blob_max`` bytes as
    ``{"_blob": sha256, "length": n}``, over it only described."""
    if isinstance(value, list):
        return [to_blobs(item, blobs, blob_max) for item in value]
    if not isinstance(value, dict):
        return value
    if isinstance(value.get(RAW_KEY), bytes):
        return _blob(value[RAW_KEY], blobs, blob_max)
    if BYTES_KEY in value and isinstance(value.get("length"), int) and value["length"] > BLOB_FROM:
        return _blob(base64.b64decode(value[BYTES_KEY]), blobs, blob_max)
    return {key: to_blobs(item, blobs, blob_max) for key, item in value.items()}


def with_raw(value: Any, raw: Sequence[bytes]) -> Any:
    """``value`` with each ``{"_raw": i, "length": n}`` holding the ``i``-th of ``raw`` instead of
    ``i``: the arrays the live bridge's ROS side sends after a message's line."""
    if isinstance(value, list):
        return [with_raw(item, raw) for item in value]
    if not isinstance(value, dict):
        return value
    if isinstance(value.get(RAW_KEY), int):
        return {**value, RAW_KEY: raw[value[RAW_KEY]]}
    return {key: with_raw(item, raw) for key, item in value.items()}


def _blob(data: bytes, blobs: dict[str, bytes], blob_max: int) -> dict[str, Any]:
    if len(data) > blob_max:
        return described(data, len(data))
    digest = hashlib.sha256(data).hexdigest()
    blobs[digest] = data
    return {BLOB_KEY: digest, "length": len(data)}


def byte_arrays(value: Any, key: str) -> Iterator[dict[str, Any]]:
    """Every kept or described byte array of ``value`` whose marker is ``key`` (:data:`BLOB_KEY`,
    :data:`TRUNCATED_KEY`)."""
    if isinstance(value, list):
        for item in value:
            yield from byte_arrays(item, key)
    elif isinstance(value, dict):
        if key in value:
            yield value
        else:
            for item in value.values():
                yield from byte_arrays(item, key)
