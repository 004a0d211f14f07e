"""The envelope every event travels in, and parsing of raw message bodies.

An event is known by (robot, epoch, seq). Every start of a robot's client mints a new epoch
(:func:`new_epoch`) and numbers its events 0, 1, 2, ... within it, so a robot whose personal
database was lost, or two processes with the same account, never reuse a number, and a resend
(built once, kept in the outbox with its epoch and number) is still an exact duplicate.

What an event *is* beyond its key is its content: its type and its body, compared as validated
JSON (:func:`content_digest`). A resend is the same key with the same content, whatever optional
fields it leaves out or stamps anew (``message_id``, ``sent_at``); the same key with other content
is a reused number. An event sent without a ``message_id`` gets one derived from its key and
content (:func:`derived_message_id`), so every delivery and every resend of it carries the same.
fleetbus's own robot client names its events by their key alone (:func:`keyed_message_id`): it
builds each event once and resends it from its outbox as it was, so the content need not be hashed
on the robot (a 512 KB chunk's digest cost 2 ms there); the worker still hashes it to compare sends.
"""

from __future__ import annotations

import hashlib
import json
import secrets
import uuid
from datetime import datetime, timezone
from typing import Annotated, Any, Literal, Union

from pydantic import (
    AwareDatetime,
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from fleetbus.schemas.bodies import (
    INT64_MAX,
    BeaconSighting,
    BehaviourOutcome,
    HazardDetected,
    LocalisationState,
    MapChunk,
    MapUpdate,
    Measurement,
    RobotStatus,
    RosChunk,
)
from fleetbus.schemas.identity import RobotId
from fleetbus.schemas.ros import RosMessage
from fleetbus.schemas.routing import EventType

#: 2: the envelope carries the ``epoch`` its sequence number belongs to (version 1 had none).
SCHEMA_VERSION = 2
#: UTC time to the millisecond, then 32 random bits: ``20261124T205601123Z-9f3a2c1b``. Epochs of one
#: robot sort as text in the order they began (by the robot's clock).
EPOCH_PATTERN = r"^[0-9]{8}T[0-9]{9}Z-[0-9a-f]{8}$"


def new_epoch(now: datetime | None = None) -> str:
    """A new epoch, in the form of :data:`EPOCH_PATTERN`: ``now`` (default: the clock) and random bits."""
    moment = (now or datetime.now(timezone.utc)).astimezone(timezone.utc)
    return f"{moment:%Y%m%dT%H%M%S}{moment.microsecond // 1000:03d}Z-{secrets.token_hex(4)}"


#: The namespace of the message ids derived for events sent without one (a fixed, random UUID).
MESSAGE_ID_NAMESPACE = uuid.UUID("6d1f4c1e-5b0a-4e27-9f0c-3f6b1a2e8d47")


def content_digest(event_type: EventType | str, body: BaseModel) -> str:
    """SHA-256 of the event's content: its type and its validated body as canonical JSON (keys
    sorted, no spaces), so key order, white space and optional fields left at their defaults do
    not change it. Two sends of one (robot, epoch, seq) are one event exactly when these agree."""
    canonical = json.dumps(
        {"type": EventType(event_type).value, "body": body.model_dump(mode="json")},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(canonical.encode()).hexdigest()


def derived_message_id(robot_id: str, epoch: str, seq: int, digest: str) -> uuid.UUID:
    """The message id of an event sent without one: the same for every send of the same event."""
    return uuid.uuid5(MESSAGE_ID_NAMESPACE, f"{robot_id}/{epoch}/{seq}/{digest}")


#: The namespace of the ids fleetbus's robot client gives its events (another fixed, random UUID,
#: so that no keyed id can equal a derived one).
KEYED_MESSAGE_ID_NAMESPACE = uuid.UUID("a3c0e2f4-7d1b-4a85-b6e9-52f0d8c41b7a")


def keyed_message_id(robot_id: str, epoch: str, seq: int) -> uuid.UUID:
    """The message id of an event numbered by a client that builds it once and resends it as it
    was (fleetbus's robot client): its key names it, with no digest of its content."""
    return uuid.uuid5(KEYED_MESSAGE_ID_NAMESPACE, f"{robot_id}/{epoch}/{seq}")


#: What ``message_id`` holds until the validator derives it (never seen outside validation).
_UNDERIVED = uuid.UUID(int=0)


def _type_required(schema: dict[str, Any]) -> None:
    """``type`` has a default for Python callers, but a message must carry it: the parser picks
    the event's model by it (a message without one is refused as ``schema``)."""
    required = schema.setdefault("required", [])
    if "type" not in required:
        required.append("type")


class _EnvelopeBase(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, json_schema_extra=_type_required)

    message_id: uuid.UUID = Field(
        # replaced at once by the derived id (_derive_message_id); a factory, not a default, keeps
        # a placeholder out of the published schema, and a constant spares a random id per event
        default_factory=lambda: _UNDERIVED,
        description="optional: when left out, fleetbus derives it from robot_id, epoch, seq, type "
        "and body, so a resend of the same event carries the same id",
    )
    robot_id: RobotId
    epoch: str = Field(
        pattern=EPOCH_PATTERN,
        description="the start of the robot's client that numbered this event (UTC time, random bits)",
    )
    seq: int = Field(ge=0, le=INT64_MAX, description="the event's number within its epoch: 0, 1, 2, ...")
    sent_at: AwareDatetime = Field(
        default_factory=lambda: datetime.now(timezone.utc),
        description="when the robot sent it (with its time zone); left out, the time the worker read it: "
        "the gate orders a warden's localisations by it, and `late` is measured from it",
    )
    schema_version: Literal[2] = SCHEMA_VERSION

    @model_validator(mode="after")
    def _derive_message_id(self) -> _EnvelopeBase:
        if "message_id" not in self.model_fields_set:
            digest = content_digest(self.type, self.body)  # type: ignore[attr-defined]
            derived = derived_message_id(self.robot_id, self.epoch, self.seq, digest)
            object.__setattr__(self, "message_id", derived)  # frozen: set once, while validating
        return self


class HazardEvent(_EnvelopeBase):
    type: Literal[EventType.HAZARD] = EventType.HAZARD
    body: HazardDetected


class MapEvent(_EnvelopeBase):
    type: Literal[EventType.MAP] = EventType.MAP
    body: MapUpdate


class MapChunkEvent(_EnvelopeBase):
    type: Literal[EventType.MAP_CHUNK] = EventType.MAP_CHUNK
    body: MapChunk


class StatusEvent(_EnvelopeBase):
    type: Literal[EventType.STATUS] = EventType.STATUS
    body: RobotStatus


class LocalisationEvent(_EnvelopeBase):
    type: Literal[EventType.LOCALISATION] = EventType.LOCALISATION
    body: LocalisationState


class BeaconEvent(_EnvelopeBase):
    type: Literal[EventType.BEACON] = EventType.BEACON
    body: BeaconSighting


class BehaviourEvent(_EnvelopeBase):
    type: Literal[EventType.BEHAVIOUR] = EventType.BEHAVIOUR
    body: BehaviourOutcome


class RosEvent(_EnvelopeBase):
    type: Literal[EventType.ROS] = EventType.ROS
    body: RosMessage


class RosChunkEvent(_EnvelopeBase):
    type: Literal[EventType.ROS_CHUNK] = EventType.ROS_CHUNK
    body: RosChunk


class MeasurementEvent(_EnvelopeBase):
    type: Literal[EventType.MEASUREMENT] = EventType.MEASUREMENT
    body: Measurement


Event = Annotated[
    Union[  # noqa: UP007
        HazardEvent,
        MapEvent,
        MapChunkEvent,
        StatusEvent,
        LocalisationEvent,
        BeaconEvent,
        BehaviourEvent,
        RosEvent,
        RosChunkEvent,
        MeasurementEvent,
    ],
    Field(discriminator="type"),
]
EVENT_MODELS: dict[EventType, type[_EnvelopeBase]] = {
    EventType.HAZARD: HazardEvent,
    EventType.MAP: MapEvent,
    EventType.MAP_CHUNK: MapChunkEvent,
    EventType.STATUS: StatusEvent,
    EventType.LOCALISATION: LocalisationEvent,
    EventType.BEACON: BeaconEvent,
    EventType.BEHAVIOUR: BehaviourEvent,
    EventType.ROS: RosEvent,
    EventType.ROS_CHUNK: RosChunkEvent,
    EventType.MEASUREMENT: MeasurementEvent,
}
BODY_MODELS: dict[EventType, type[BaseModel]] = {
    t: m.model_fields["body"].annotation
    for t, m in EVENT_MODELS.items()  # type: ignore[misc]
}
EVENT_ADAPTER: TypeAdapter[Event] = TypeAdapter(Event)


class SchemaError(ValueError):
    """A message that is not a valid event; ``str()`` names every offending field."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("; ".join(problems))


class NotJSONError(SchemaError):
    """The body is not JSON at all."""


def describe_validation_error(error: ValidationError, prefix: str = "") -> list[str]:
    problems = []
    for item in error.errors(include_url=False):
        location = ".".join(str(part) for part in item["loc"]) or "(message)"
        message = item["msg"]
        if item["type"] == "union_tag_not_found":  # the discriminator itself is missing
            location = ".".join([*map(str, item["loc"]), "type"])
            message = f"Field required (one of {', '.join(t.value for t in EventType)})"
        problems.append(f"{prefix}{location}: {message}")
    return problems


def parse_event(raw: bytes | str) -> Event:
    """Validate a JSON message body; raise :class:`SchemaError` naming what is wrong.

    Strictly, as the AsyncAPI document describes the message: a number or a boolean sent as a
    string (``"seq": "7"``, ``"localised": "yes"``) is refused, not converted. Python callers of
    :func:`validate_body` keep pydantic's conversions; the JSON the client sends is canonical."""
    try:
        return EVENT_ADAPTER.validate_json(raw, strict=True)
    except ValidationError as error:
        problems = describe_validation_error(error)
        if any(item["type"] == "json_invalid" for item in error.errors()):
            raise NotJSONError(problems) from None
        raise SchemaError(problems) from None


def validate_body(event_type: EventType | str, data: Any) -> BaseModel:
    """Validate just a body (what a robot hands to the client) against its type's model."""
    model = BODY_MODELS[EventType(event_type)]
    if isinstance(data, model):
        return data
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise SchemaError(describe_validation_error(error, prefix="body.")) from None


def build_event(
    event_type: EventType | str, robot_id: str, epoch: str, seq: int, body: Any, **envelope: Any
) -> Event:
    model = EVENT_MODELS[EventType(event_type)]
    return model(robot_id=robot_id, epoch=epoch, seq=seq, body=validate_body(event_type, body), **envelope)  # type: ignore[return-value]


def encode_event(event: BaseModel) -> bytes:
    return event.model_dump_json().encode()
