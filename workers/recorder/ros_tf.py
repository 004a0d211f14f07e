"""Each transform of a recorded ``tf2_msgs/TFMessage`` as a record of its own, to query by frames.

A TF message holds a list of transforms; a query such as "the transforms from frame A to child
frame B in this time range" is about one transform, not the message that carried it with others.
So every ``ros`` record of a TF type (live or imported) is followed by one ``ros_tf`` record per
transform, flat as the reference's documents are:

==================  ===============================================================
field               value
==================  ===============================================================
``topic``           the message's topic (``/tf``, ``/tf_static``)
``frame_id``        the transform's ``header.frame_id`` (the parent frame)
``child_frame_id``  its ``child_frame_id``
``stamp``           its ``header.stamp`` (ISO 8601; also the record's ``sent_at``)
``translation``     ``{x, y, z}``
``rotation``        ``{x, y, z, w}``
``message``         the key of the ``ros`` record it came from
``index``           its position in that message's ``transforms``
==================  ===============================================================

The record keeps the message's robot, routing key and recording time, and its key is made of the
message's key and the index: recorded again, it is stored once.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from typing import Any

from fleetbus.schemas.ros import ROS_TF_TYPE, ROS_TYPE
from fleetbus.workers.recorder.ros_fields import header_stamp
from fleetbus.workers.store.recordings import RecordedMessage

#: The ROS types whose messages are lists of transforms (ROS 1's old ``tf`` and ``tf2_msgs``).
TF_TYPES = frozenset({"tf2_msgs/msg/TFMessage", "tf/msg/tfMessage", "tf2_msgs/TFMessage", "tf/tfMessage"})


def transform_key(message_key: str, index: int) -> str:
    return hashlib.sha256(f"tf\0{message_key}\0{index}".encode()).hexdigest()[:32]


def transform_document(topic: str, message_key: str, index: int, transform: Any) -> dict[str, Any] | None:
    """One ``geometry_msgs/TransformStamped`` document as a ``ros_tf`` document; None when it is not one."""
    if not isinstance(transform, dict):
        return None
    header = transform.get("header")
    moved = transform.get("transform")
    if not isinstance(header, dict) or not isinstance(moved, dict):
        return None
    stamp = header_stamp(transform)
    return {
        "topic": topic,
        "frame_id": header.get("frame_id"),
        "child_frame_id": transform.get("child_frame_id"),
        "stamp": stamp.isoformat() if stamp else None,
        "translation": moved.get("translation"),
        "rotation": moved.get("rotation"),
        "message": message_key,
        "index": index,
    }


def transform_records(record: RecordedMessage) -> list[RecordedMessage]:
    """The ``ros_tf`` records of a ``ros`` record of a TF type; none for any other record."""
    document = record.document
    if record.type != ROS_TYPE or not isinstance(document, dict) or document.get("ros_type") not in TF_TYPES:
        return []
    fields = document.get("fields")
    transforms = fields.get("transforms") if isinstance(fields, dict) else None
    if not isinstance(transforms, list):
        return []
    records = []
    for index, transform in enumerate(transforms):
        found = transform_document(str(document.get("topic")), record.key, index, transform)
        if found is None:
            continue
        stamp = header_stamp(transform)
        records.append(
            replace(
                record,
                key=transform_key(record.key, index),
                type=ROS_TF_TYPE,
                sent_at=stamp,
                seq=index,
                message_id=None,  # the message's trace shows the message; "message" names it
                document=found,
                raw=None,
                problem=None,
                properties={"type": document.get("ros_type")},
                size=len(json.dumps(found, separators=(",", ":"))),
                received=None,
            )
        )
    return records
