"""A site's uplink to central, in classes: each its own queue, bound, overflow policy and shovel.

One FIFO for everything let a full uplink refuse the robots' hazards because telemetry filled it,
and after an outage a hazard waited behind all the telemetry queued before it. Now:

* **hazards** (``fleetbus.uplink.hazards``): hazard events. Never dropped: full, the site's broker
  refuses the robot's publish (``reject-publish``) and the event waits in the robot's outbox.
  A shovel of its own, so a hazard never waits behind anything else queued for central.
* **events** (``fleetbus.uplink``): maps and their chunks, behaviour outcomes, beacon sightings,
  ROS messages. Never dropped, refused when full, as above; in one queue so a map's chunks keep
  their order before the map.
* **telemetry** (``fleetbus.uplink.telemetry``): status and localisation. Full, it drops its oldest
  (``drop-head``), dead-lettered to ``fleetbus.overflow`` where the site's worker counts them
  (``fleetbus stats``): telemetry never fills the site's link for the others, and never makes the
  site refuse a robot.

The hazard states the site's worker makes (:mod:`fleetbus.workers.hazard_uplink`) have their own
queue and shovel already (:mod:`fleetbus.broker.sites`), bounded like the events.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from fleetbus.schemas.routing import UPLINK_QUEUE, UPLINK_SHOVEL, EventType

REFUSE = "reject-publish"
DROP_OLDEST = "drop-head"


@dataclass(frozen=True)
class UplinkClass:
    name: str
    queue: str
    shovel: str
    types: tuple[EventType, ...]
    overflow: str
    """``reject-publish`` (never dropped: the robot's outbox keeps it) or ``drop-head`` (counted)."""

    def keys(self, robot: str) -> list[str]:
        """The routing keys that bind ``robot``'s events of this class from ``fleetbus.ingest``."""
        return [f"{robot}.{event_type.value}" for event_type in self.types]


HAZARDS = UplinkClass(
    "hazards", "fleetbus.uplink.hazards", "fleetbus-uplink-hazards", (EventType.HAZARD,), REFUSE
)
TELEMETRY = UplinkClass(
    "telemetry",
    "fleetbus.uplink.telemetry",
    "fleetbus-uplink-telemetry",
    (EventType.STATUS, EventType.LOCALISATION),
    DROP_OLDEST,
)
EVENTS = UplinkClass(
    "events",
    UPLINK_QUEUE,
    UPLINK_SHOVEL,
    tuple(t for t in EventType if t not in (*HAZARDS.types, *TELEMETRY.types)),
    REFUSE,
)
#: Every class, the most urgent first.
CLASSES = (HAZARDS, EVENTS, TELEMETRY)
BY_QUEUE = {uplink.queue: uplink for uplink in CLASSES}


@dataclass(frozen=True)
class UplinkBounds:
    """Each class's bound in messages, and the bytes bound of the classes never dropped."""

    hazards: int
    events: int
    telemetry: int
    max_bytes: int

    def of(self, uplink: UplinkClass) -> int:
        return {"hazards": self.hazards, "events": self.events, "telemetry": self.telemetry}[uplink.name]


class UplinkSettings(Protocol):
    @property
    def uplink_hazards_max(self) -> int: ...
    @property
    def uplink_max(self) -> int: ...
    @property
    def uplink_telemetry_max(self) -> int: ...
    @property
    def uplink_max_bytes(self) -> int: ...


def bounds_of(settings: UplinkSettings) -> UplinkBounds:
    """The bounds the settings give (``FLEETBUS_UPLINK_*``)."""
    return UplinkBounds(
        hazards=settings.uplink_hazards_max,
        events=settings.uplink_max,
        telemetry=settings.uplink_telemetry_max,
        max_bytes=settings.uplink_max_bytes,
    )
