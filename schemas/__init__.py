"""pydantic models of every message on the fleetbus bus, and the routing convention."""

from fleetbus.schemas.bodies import (
    BeaconSighting,
    BehaviourOutcome,
    HazardDetected,
    LocalisationState,
    MapMetadata,
    MapUpdate,
    Pose,
    Quaternion,
    RobotStatus,
)
from fleetbus.schemas.envelope import (
    BODY_MODELS,
    EVENT_MODELS,
    Event,
    SchemaError,
    build_event,
    encode_event,
    parse_event,
    validate_body,
)
from fleetbus.schemas.identity import RobotId, validate_name
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import EventType, RobotKind, Topic

__all__ = [
    "BODY_MODELS",
    "EVENT_MODELS",
    "BeaconSighting",
    "BehaviourOutcome",
    "Event",
    "EventType",
    "HazardDetected",
    "LocalisationState",
    "MapMetadata",
    "MapUpdate",
    "Notification",
    "Pose",
    "Quaternion",
    "RobotId",
    "RobotKind",
    "RobotStatus",
    "SchemaError",
    "Topic",
    "build_event",
    "encode_event",
    "parse_event",
    "validate_body",
    "validate_name",
]
