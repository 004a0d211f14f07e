"""The records a recorded ROS message brings with it: each transform of a TF message
(:mod:`ros_tf`), and the definition of its type when the message carries it (:mod:`ros_native`).
Keyed by what they copy, so recording a message again stores nothing twice."""

from __future__ import annotations

from fleetbus.schemas.ros import ROS_TYPE, RosDefinition
from fleetbus.workers.recorder.ros_native import RosSchema, schema_record
from fleetbus.workers.recorder.ros_tf import transform_records
from fleetbus.workers.store.recordings import RecordedMessage


def derived_records(record: RecordedMessage) -> list[RecordedMessage]:
    if record.type != ROS_TYPE or not isinstance(record.document, dict):
        return []
    derived = transform_records(record)
    carried = record.document.get("definition")
    if isinstance(carried, dict):
        definition = RosDefinition.model_validate(carried)
        schema = RosSchema(
            str(record.document.get("ros_type")), definition.encoding, definition.text, definition.md5sum
        )
        topic = str(record.document.get("topic"))
        derived.append(schema_record(schema, record.robot_id or "", topic, record.recorded_at))
    return derived
