"""pydantic models of every message on the fleetbus bus, and the routing convention.

The names below are imported when first used (PEP 562), so a process that needs only the routing
convention (``fleetbus.schemas.routing``: the recorder) does not load pydantic and every model.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

_MODULES = {
    "bodies": (
        "BeaconSighting",
        "BehaviourOutcome",
        "HazardDetected",
        "LocalisationState",
        "MapMetadata",
        "MapUpdate",
        "Pose",
        "Quaternion",
        "RobotStatus",
    ),
    "envelope": (
        "BODY_MODELS",
        "EVENT_MODELS",
        "Event",
        "SchemaError",
        "build_event",
        "encode_event",
        "parse_event",
        "validate_body",
    ),
    "identity": ("RobotId", "validate_name"),
    "notifications": ("Notification",),
    "routing": ("EventType", "RobotKind", "Topic"),
}
_MODULE_OF = {name: module for module, names in _MODULES.items() for name in names}

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


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
