"""A recorded window of one robot's ROS messages published again on a ROS master
(``fleetbus ros replay``): on their original topics (or under a prefix), as their original
types, at the recorded pace or faster or slower by a factor.

The messages are serialised again here (:mod:`ros_native`) and handed, with their types'
definitions, to a ROS-side process on the ROS machine's Python (``publishers/ros/ros_replay.py``,
which needs rospy), as JSON lines; it publishes each when its time comes.
"""

from __future__ import annotations

import base64
import json
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from fleetbus.schemas.ros import ROS_TYPE
from fleetbus.workers.recorder.export_selection import log_time_ns
from fleetbus.workers.recorder.ros_native import Codec, NotEncodable, RosSchema
from fleetbus.workers.store.recordings import RecordedMessage

ROS_REPLAY = Path(__file__).resolve().parents[2] / "publishers" / "ros" / "ros_replay.py"


class ReplayError(RuntimeError):
    """The replay could not run; the message says why."""


@dataclass(frozen=True)
class ReplayOptions:
    python: str = "/usr/bin/python3"
    speed: float = 1.0
    """Faster (2.0) or slower (0.5) than recorded."""
    subscribers: int = 0
    """Wait until every topic has this many subscribers before the first message."""
    wait_s: float = 30.0
    delay_s: float = 0.2
    """After the publishers are up (and the subscribers wanted are there): time for subscribers to
    connect and start reading before the first message (``rosbag play --delay``; 0.2 s by default)."""
    prefix: str = ""
    """Published under this namespace (``/replay``): ``/replay/scan``; none: the original topics."""
    env: dict[str, str] | None = None


@dataclass
class ReplayReport:
    published: dict[str, int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)
    """ROS messages not replayed, per why (no definition recorded, not serialisable again)."""


def ros_messages(records: Iterable[RecordedMessage]) -> Iterable[tuple[RecordedMessage, dict[str, Any]]]:
    for record in records:
        if record.type == ROS_TYPE and isinstance(record.document, dict):
            yield record, record.document


def topics_of(records: Iterable[RecordedMessage], schemas: Mapping[str, RosSchema]) -> dict[str, RosSchema]:
    """The first pass: each topic of the window and its type's definition."""
    topics: dict[str, RosSchema] = {}
    for _, document in ros_messages(records):
        schema = schemas.get(str(document.get("schema_key")))
        if schema is not None:
            topics.setdefault(str(document["topic"]), schema)
    return topics


def replay_into_ros(
    survey: Iterable[RecordedMessage],
    records: Iterable[RecordedMessage],
    schemas: Mapping[str, RosSchema],
    options: ReplayOptions,
) -> ReplayReport:
    """Publish ``records`` (read twice: ``survey`` first, for the topics) on the ROS master."""
    topics = topics_of(survey, schemas)
    if not topics:
        raise ReplayError("nothing to replay: no ROS message with a recorded definition in the window")
    try:
        side = subprocess.Popen(
            [options.python, str(ROS_REPLAY)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=options.env,
        )
    except OSError as error:
        raise ReplayError(f"cannot start the ROS side with {options.python!r}: {error}") from None
    assert side.stdin is not None and side.stdout is not None
    report = ReplayReport()
    try:
        expect(side.stdout, "ready")
        codecs = {schema.key: Codec(schema) for schema in topics.values()}
        for topic, schema in topics.items():
            definition, md5sum = codecs[schema.key].ros1_definition()
            item = {"topic": options.prefix + topic, "type": schema.ros1_type, "md5sum": md5sum}
            send(side.stdin, "advertise", **item, definition=definition)
        wait = {"subscribers": options.subscribers, "timeout": options.wait_s, "delay": options.delay_s}
        send(side.stdin, "start", **wait)
        expect(side.stdout, "started")
        first: int | None = None
        for record, document in ros_messages(records):
            topic = str(document["topic"])
            schema = topics.get(topic)
            if schema is None or schema.key != document.get("schema_key"):
                why = "recorded without its type's definition"
                report.left_out[why] = report.left_out.get(why, 0) + 1
                continue
            try:
                data = codecs[schema.key].serialize_ros1(document.get("fields") or {})
            except NotEncodable as error:
                report.left_out[str(error)] = report.left_out.get(str(error), 0) + 1
                continue
            at = log_time_ns(record)
            first = at if first is None else first
            at_ns = round((at - first) / options.speed)
            encoded = base64.b64encode(data).decode()
            send(side.stdin, "message", topic=options.prefix + topic, at_ns=at_ns, data=encoded)
        side.stdin.close()
        done = expect(side.stdout, "done")
        report.published = {topic.removeprefix(options.prefix): n for topic, n in done["published"].items()}
    except (BrokenPipeError, ReplayError) as error:
        side.kill()
        raise ReplayError(f"the ROS side ended ({side.wait()}): {error}") from None
    side.wait(30)
    return report


def send(stream: IO[str], kind: str, **item: Any) -> None:
    stream.write(json.dumps({"kind": kind, **item}) + "\n")
    stream.flush()


def expect(stream: IO[str], kind: str) -> dict[str, Any]:
    for line in stream:
        item: dict[str, Any] = json.loads(line)
        if item.get("kind") == kind:
            return item
        if item.get("kind") == "error":
            raise ReplayError(str(item.get("error")))
    raise ReplayError(f"it ended before saying {kind!r} (is rospy installed, and ROS_MASTER_URI a master?)")
