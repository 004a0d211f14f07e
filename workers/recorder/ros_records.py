"""The recording's record of one ROS message, as :mod:`fleetbus.schemas.ros` names it.

Whatever brings ROS messages into the recording (a bag import, a live bridge) builds its records
here, so that they are all alike.
"""

from __future__ import annotations

from typing import Any

from fleetbus.schemas.ros import ROS_EXCHANGE, ROS_TYPE, RosMessage, ros_routing_key
from fleetbus.workers.recorder.ros_fields import nanos_to_datetime
from fleetbus.workers.store.recordings import RecordedMessage

TRIMMED = "arrays over the size limit described, not kept"


def ros_record(
    robot: str,
    message: RosMessage,
    key: str,
    *,
    size: int,
    seq: int | None = None,
    trimmed: bool = False,
    properties: dict[str, Any] | None = None,
) -> RecordedMessage:
    """``message`` of ``robot`` under ``key`` (:func:`fleetbus.schemas.ros.ros_record_key`);
    ``size`` is the serialised message's bytes, ``trimmed`` that large arrays were described."""
    return RecordedMessage(
        key=key,
        type=ROS_TYPE,
        recorded_at=nanos_to_datetime(message.log_time_ns),
        exchange=ROS_EXCHANGE,
        routing_key=ros_routing_key(robot, message.topic),
        user_id=None,
        robot_id=robot,
        sent_at=message.stamp,
        seq=seq,
        known=True,
        problem=TRIMMED if trimmed else None,
        document=message.model_dump(mode="json", exclude=None if message.definition else {"definition"}),
        properties={"type": message.ros_type, **(properties or {})},
        size=size,
    )
