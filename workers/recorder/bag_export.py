"""Write recorded ROS messages to a ROS 1 bag (``fleetbus export --bag``), for ``rosbag`` and the
rosbag API: one connection per robot and topic (``/explorer1/scan``), each with its type's
definition and MD5 as a ROS 1 publisher would send them, the messages at their log times.

Messages of ROS 2 bags are written as ROS 1 messages of the same type (``rosbags`` writes the
ROS 1 definition of the type); anything else recorded (fleetbus's own events) has no place in a
ROS bag and is left out. Written with ``rosbags``' own bag writer, uncompressed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from fleetbus.schemas.ros import ROS_TYPE
from fleetbus.workers.recorder.export_selection import log_time_ns
from fleetbus.workers.recorder.mcap_export import SERVICE_TOPIC, ExportReport
from fleetbus.workers.recorder.ros_native import Codec, NotEncodable, RosSchema
from fleetbus.workers.store.recordings import RecordedMessage

NO_DEFINITION = "recorded without its type's definition"


def export_bag(
    records: Iterable[RecordedMessage],
    path: Path,
    schemas: Mapping[str, RosSchema],
    on_each: Callable[[RecordedMessage], None] = lambda record: None,
) -> ExportReport:
    """Write the ROS messages of ``records`` (in recording order) to a new ROS 1 bag at ``path``."""
    from rosbags.rosbag1 import Writer

    report = ExportReport()
    codecs: dict[str, Codec] = {}
    connections: dict[tuple[str, str], Any] = {}
    definitions: dict[str, tuple[str, str]] = {}
    path.unlink(missing_ok=True)  # the writer refuses an existing file: a partial one of before
    with Writer(path) as writer:
        for record in records:
            on_each(record)
            document = record.document
            if record.type != ROS_TYPE or not isinstance(document, dict):
                continue
            schema = schemas.get(str(document.get("schema_key")))
            if schema is None:
                report.not_encoded[NO_DEFINITION] = report.not_encoded.get(NO_DEFINITION, 0) + 1
                continue
            codec = codecs.get(schema.key) or codecs.setdefault(schema.key, Codec(schema))
            try:
                data = codec.serialize_ros1(document.get("fields") or {})
            except NotEncodable as error:
                why = str(error)
                report.not_encoded[why] = report.not_encoded.get(why, 0) + 1
                continue
            topic = f"/{record.robot_id or SERVICE_TOPIC}{document.get('topic')}"
            # one connection per topic and definition: a ROS 1 and a ROS 2 import of one type on
            # one topic are two schema records with the same ROS 1 definition
            definition, md5sum = definitions.get(schema.key) or definitions.setdefault(
                schema.key, codec.ros1_definition()
            )
            connection = connections.get((topic, md5sum))
            if connection is None:
                connection = connections[topic, md5sum] = writer.add_connection(
                    topic, schema.ros_type, msgdef=definition, md5sum=md5sum
                )
            writer.write(connection, log_time_ns(record), data)
            report.channels[topic] = report.channels.get(topic, 0) + 1
            report.messages += 1
    return report
