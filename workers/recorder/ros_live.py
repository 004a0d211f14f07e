"""A ``ros`` event from the live bridge, recorded as every ROS message is (``fleetbus.schemas.ros``).

The bridge publishes each ROS message as a ``ros`` event through the robot's outbox; the recorder
keeps it like a message imported from a bag: type ``ros``, exchange ``ros``, key
``<robot>.ros.<topic>``, the :class:`RosMessage` as the document, recorded at its ROS log time
(when the bridge received it), ``sent_at`` its header stamp. Where it travelled on the bus
(exchange, routing key) stays in its headers. Its record key comes from the robot's epoch and
sequence number, so a redelivered event is recorded once.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pydantic import ValidationError

from fleetbus.schemas.ros import TRUNCATED_KEY, RosMessage, byte_arrays, ros_record_key
from fleetbus.workers.recorder.ros_records import ros_record
from fleetbus.workers.store.recordings import RecordedMessage

BUS_EXCHANGE_HEADER = "x-fleetbus-exchange"
BUS_ROUTING_KEY_HEADER = "x-fleetbus-routing-key"
OVER_BOUND = "byte arrays over the robot's bound (FLEETBUS_ROS_BLOB_MAX_BYTES) described, not kept: {sizes}"


def as_ros_record(record: RecordedMessage) -> RecordedMessage:
    """``record`` (a robot's ``ros`` event as captured) in the ROS convention; unchanged, with the
    problem said, when its body is no ROS message."""
    envelope: Any = record.document
    body = envelope.get("body") if isinstance(envelope, dict) else None
    try:
        message = RosMessage.model_validate(body)
    except ValidationError as error:
        problem = f"a ros event whose body is no ROS message: {error.error_count()} problems"
        return replace(record, problem="; ".join(p for p in (record.problem, problem) if p))
    robot = record.robot_id or ""
    epoch, seq = envelope.get("epoch"), envelope.get("seq")
    key = ros_record_key(f"{robot}/{epoch}", seq) if isinstance(seq, int) and epoch else record.key
    headers = {
        **(record.properties.get("headers") or {}),
        BUS_EXCHANGE_HEADER: record.exchange,
        BUS_ROUTING_KEY_HEADER: record.routing_key,
    }
    properties = {name: value for name, value in record.properties.items() if name != "type"}
    built = ros_record(
        robot, message, key, size=record.size, seq=record.seq, properties={**properties, "headers": headers}
    )
    # what the broker validated and the capture found stay as they were
    over = [str(array.get("length")) for array in byte_arrays(message.fields, TRUNCATED_KEY)]
    said = OVER_BOUND.format(sizes=", ".join(f"{size} bytes" for size in over)) if over else None
    problem = "; ".join(p for p in (record.problem, said) if p) or None
    kept = {"user_id": record.user_id, "known": record.known, "problem": problem}
    return replace(built, **kept, message_id=record.message_id)
