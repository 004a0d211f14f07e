"""The envelope every event travels in, and parsing of raw message bodies.

An event is known by (robot, epoch, seq). Every start of a robot's client mints a new epoch
(:func:`new_epoch`) and numbers its events 0, 1, 2, ... within it, so a robot whose personal
database was lost, or two processes with the same account, never reuse a number, and a resend
(built once, kept in the outbox with its epoch and number) is still an exact duplicate.
"""

from __future__ import annotations

import secrets
import uuid
from datetime import datetime, timezone
from typing import Annotated, Any, Literal, Union

from pydantic import (
    AwareDatetime,
    BaseModel,
    ConfigDict,
    Field,
    NonNegativeInt,
    TypeAdapter,
    ValidationError,
)

from fleetbus.schemas.bodies import (
    BeaconSighting,
    BehaviourOutcome,
    HazardDetected,
    LocalisationState,
    MapChunk,
    MapUpdate,
    RobotStatus,
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


class _EnvelopeBase(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    message_id: uuid.UUID = Field(default_factory=uuid.uuid4)
    robot_id: RobotId
    epoch: str = Field(
        pattern=EPOCH_PATTERN,
        description="the start of the robot's client that numbered this event (UTC time, random bits)",
    )
    seq: NonNegativeInt = Field(description="the event's number within its epoch: 0, 1, 2, ...")
    sent_at: AwareDatetime = Field(default_factory=lambda: datetime.now(timezone.utc))
    schema_version: Literal[2] = SCHEMA_VERSION


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
        problems.append(f"{prefix}{location}: {item['msg']}")
    return problems


def parse_event(raw: bytes | str) -> Event:
    """Validate a JSON message body; raise :class:`SchemaError` naming what is wrong."""
    try:
        return EVENT_ADAPTER.validate_json(raw)
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
