"""Write recorded messages to an MCAP file that Foxglove opens with something to show.

Channels, all ``json`` messages with ``jsonschema`` schemas:

=================================  ==========================  =================================
topic                              schema                      message
=================================  ==========================  =================================
``/<robot>/<type>``                ``fleetbus.<type>``: the    the recorded document (a
(``/fleetbus/<type>`` for the      pydantic model's JSON       fleetbus event envelope, a
service's messages)                Schema                      notification...)
``/<robot>/map/grid``              ``foxglove.Grid``           an inline map image
``/<robot>/status/pose``,          ``foxglove.PoseInFrame``    the pose of a status or a
``/<robot>/localisation/pose``                                 localisation
``/<robot>/hazards``               ``foxglove.SceneUpdate``    a sphere and a label per hazard
``/<robot><topic>``                the ROS type's definition   the ROS message in its native
(``/explorer1/scan``)              (``ros1msg`` or             encoding (``ros1`` or ``cdr``),
                                   ``ros2msg``)                serialised again from its fields
=================================  ==========================  =================================

A ROS message recorded without its type's definition (a recording older than definitions) is
written as JSON (its fields) with an open JSON Schema instead.

Log time is when the message was recorded (a bag's log time for imported ROS messages, to the
nanosecond); publish time is when it was sent (the envelope's ``sent_at``, ``header.stamp``
for ROS), else the log time. The records are written as they are read: the file is streamed,
one MCAP chunk in memory at a time, whatever the length of the window.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, BinaryIO

from pydantic import BaseModel

from fleetbus.schemas.envelope import EVENT_MODELS
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.ros import ROS_TYPE
from fleetbus.workers.recorder.capture import NOTIFICATION
from fleetbus.workers.recorder.foxglove_views import VIEWS
from fleetbus.workers.recorder.ros_native import Codec, NotEncodable, RosSchema
from fleetbus.workers.store.recordings import RecordedMessage

PROFILE = ""
"""No MCAP profile: the messages are JSON, not ROS-serialised."""
LIBRARY = "fleetbus export"
SERVICE_TOPIC = "fleetbus"
"""The first topic segment of messages no robot sent (notifications)."""
RAW_KEY = "_raw_base64"
"""A body kept raw (not JSON) is written as ``{"_raw_base64": "...", "problem": "..."}``."""

_MODELS: dict[str, type[BaseModel]] = {
    **{t.value: m for t, m in EVENT_MODELS.items()},
    NOTIFICATION: Notification,
}


def self_contained(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` with every ``$ref`` to its ``$defs`` replaced by the definition itself: readers
    that look for fields (Foxglove finds base64 fields by their ``contentEncoding``) need not
    resolve references. The models have no recursive types; one would be left as a reference."""
    definitions = schema.get("$defs", {})

    def inline(value: Any, seen: tuple[str, ...]) -> Any:
        if isinstance(value, dict):
            ref = value.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                name = ref.removeprefix("#/$defs/")
                if name in definitions and name not in seen:
                    rest = {k: v for k, v in value.items() if k != "$ref"}
                    return inline({**definitions[name], **rest}, (*seen, name))
            return {k: inline(v, seen) for k, v in value.items() if k != "$defs"}
        if isinstance(value, list):
            return [inline(v, seen) for v in value]
        return value

    inlined: dict[str, Any] = inline(schema, ())
    if "$ref" in json.dumps(inlined):
        return schema
    return inlined


def model_schema(model: type[BaseModel]) -> dict[str, Any]:
    return self_contained(model.model_json_schema())


def type_schema(type_name: str) -> dict[str, Any]:
    """The JSON Schema of a recorded type's documents: its pydantic model's, else any object."""
    model = _MODELS.get(type_name)
    if model is not None:
        return model_schema(model)
    return {"title": f"fleetbus.{type_name}", "type": "object"}


def nanos(moment: datetime) -> int:
    return round(moment.timestamp() * 1_000_000) * 1000


@dataclass
class ExportReport:
    messages: int = 0
    """Recorded messages written (each once, on its own type's channel or ROS topic)."""
    views: int = 0
    """Foxglove messages written besides them."""
    channels: dict[str, int] = field(default_factory=dict)
    """Messages per topic."""
    not_encoded: dict[str, int] = field(default_factory=dict)
    """ROS messages left out, per why: fields that cannot be serialised again (an array the
    recording kept only as a description)."""


class McapExport:
    """One MCAP file being written: schemas and channels registered on first use."""

    def __init__(self, stream: BinaryIO, ros_schemas: Mapping[str, RosSchema] | None = None) -> None:
        from mcap.writer import Writer

        self._writer = Writer(stream)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._ros_schemas = ros_schemas or {}
        self._codecs: dict[str, Codec] = {}
        self.report = ExportReport()

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record (what the file holds: robots, window), as MCAP readers list them."""
        self._writer.add_metadata(name, dict(data))

    def _schema(self, name: str, schema: Callable[[], dict[str, Any]]) -> int:
        if name not in self._schemas:
            data = json.dumps(schema(), separators=(",", ":")).encode()
            self._schemas[name] = self._writer.register_schema(name=name, encoding="jsonschema", data=data)
        return self._schemas[name]

    def _channel(
        self, topic: str, schema_name: str, schema: Callable[[], dict[str, Any]], **meta: str
    ) -> int:
        if (topic, schema_name) not in self._channels:
            schema_id = self._schema(schema_name, schema)
            self._channels[topic, schema_name] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id, metadata=meta
            )
        return self._channels[topic, schema_name]

    def _add(self, channel: int, topic: str, value: Any, log_time: int, publish_time: int) -> None:
        data = json.dumps(value, separators=(",", ":"), ensure_ascii=False).encode()
        self._writer.add_message(channel_id=channel, log_time=log_time, data=data, publish_time=publish_time)
        self.report.channels[topic] = self.report.channels.get(topic, 0) + 1

    def write(self, record: RecordedMessage) -> None:
        """The record on its own channel, and its Foxglove view when it has one."""
        if record.type == ROS_TYPE and isinstance(record.document, dict):
            self._write_ros(record, record.document)
            return
        log_time = nanos(record.recorded_at)
        publish_time = nanos(record.sent_at) if record.sent_at else log_time
        owner = record.robot_id or SERVICE_TOPIC
        topic = f"/{owner}/{record.type}"
        channel = self._channel(
            topic, f"fleetbus.{record.type}", lambda: type_schema(record.type), robot=record.robot_id or ""
        )
        self._add(channel, topic, _content(record), log_time, publish_time)
        self.report.messages += 1
        view = VIEWS.get(record.type)
        if view is None or record.document is None:
            return
        suffix, model, make = view
        drawn = make(record.document, record.sent_at or record.recorded_at, record.key)
        if drawn is not None:
            view_topic = f"/{owner}/{suffix}"
            title = str(model.model_config.get("title"))
            view_channel = self._channel(view_topic, title, lambda: model_schema(model), robot=owner)
            self._add(view_channel, view_topic, drawn.model_dump(mode="json"), log_time, publish_time)
            self.report.views += 1

    def _write_ros(self, record: RecordedMessage, document: dict[str, Any]) -> None:
        topic = str(document.get("topic") or record.routing_key)
        robot = record.robot_id or SERVICE_TOPIC
        channel_topic = f"/{robot}{topic}" if topic.startswith("/") else f"/{robot}/{topic}"
        ros_type = str(document.get("ros_type") or "ros")
        log_time = document.get("log_time_ns")
        log_time = log_time if isinstance(log_time, int) else nanos(record.recorded_at)
        publish_time = nanos(record.sent_at) if record.sent_at else log_time
        meta = {"robot": robot, "ros_topic": topic, "ros_type": ros_type}
        schema = self._ros_schemas.get(str(document.get("schema_key")))
        if schema is None:
            open_schema = {"title": ros_type, "type": "object"}
            channel = self._channel(channel_topic, ros_type, lambda: open_schema, **meta)
            self._add(channel, channel_topic, document.get("fields", {}), log_time, publish_time)
            self.report.messages += 1
            return
        try:
            data = self._codec(schema).serialize(document.get("fields") or {})
        except NotEncodable as error:
            why = str(error)
            self.report.not_encoded[why] = self.report.not_encoded.get(why, 0) + 1
            return
        channel = self._native_channel(channel_topic, schema, meta)
        self._writer.add_message(channel_id=channel, log_time=log_time, data=data, publish_time=publish_time)
        self.report.channels[channel_topic] = self.report.channels.get(channel_topic, 0) + 1
        self.report.messages += 1

    def _codec(self, schema: RosSchema) -> Codec:
        if schema.key not in self._codecs:
            self._codecs[schema.key] = Codec(schema)
        return self._codecs[schema.key]

    def _native_channel(self, topic: str, schema: RosSchema, meta: dict[str, str]) -> int:
        if (topic, schema.key) not in self._channels:
            if schema.key not in self._schemas:
                name = schema.ros1_type if schema.message_encoding == "ros1" else schema.ros_type
                self._schemas[schema.key] = self._writer.register_schema(
                    name=name, encoding=schema.encoding, data=schema.definition.encode()
                )
            self._channels[topic, schema.key] = self._writer.register_channel(
                topic=topic,
                message_encoding=schema.message_encoding,
                schema_id=self._schemas[schema.key],
                metadata=meta,
            )
        return self._channels[topic, schema.key]

    def finish(self) -> ExportReport:
        self._writer.finish()
        return self.report


def _content(record: RecordedMessage) -> Any:
    """What a record's message says: its document, else its raw bytes (or why they are missing)."""
    if record.raw is None:
        return record.document
    return {RAW_KEY: base64.b64encode(record.raw).decode(), "problem": record.problem or ""}


def export_mcap(
    records: Iterable[RecordedMessage],
    stream: BinaryIO,
    on_each: Callable[[RecordedMessage], None] = lambda record: None,
    ros_schemas: Mapping[str, RosSchema] | None = None,
    metadata: Mapping[str, str] | None = None,
) -> ExportReport:
    """Write ``records`` (in recording order) to ``stream`` as one MCAP file, reading them as it
    goes; ROS messages in their native encoding when ``ros_schemas`` has their definition."""
    export = McapExport(stream, ros_schemas)
    if metadata:
        export.metadata("fleetbus.export", metadata)
    for record in records:
        export.write(record)
        on_each(record)
    return export.finish()
