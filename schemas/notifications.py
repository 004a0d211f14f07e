"""What the service sends to robots and operators after it stored an event."""

from __future__ import annotations

from pydantic import AwareDatetime, BaseModel, ConfigDict

from fleetbus.defaults import LATE_AFTER_S
from fleetbus.schemas.envelope import Event
from fleetbus.schemas.routing import Topic

__all__ = ["LATE_AFTER_S", "Notification"]


class Notification(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    topic: Topic
    event: Event
    """The event exactly as the robot sent it."""
    received_at: AwareDatetime
    """When the service took the event from the broker."""
    stored_at: AwareDatetime | None = None
    """When the service had stored it, for a notification sent right after (None when it was
    sent later: a hazard held until the wardens localised, or one a warden missed)."""
    notified_at: AwareDatetime
    hazard_id: int | None = None
    """For hazards: the id the service gave it, sequential within its mission."""
    hazard_state: str | None = None
    """For hazards: ``announced`` when it is first announced; ``claimed`` or ``reached`` (by
    another warden, say) when a warden that missed it gets it later: put back in service, or its
    client rebuilding its list after a (re)connect. When an operator takes a step for a warden
    (the console), that warden is told the new state: ``claimed``, ``reached``, ``cleared``, or
    ``announced`` again after a release."""
    claimed_by: str | None = None
    """For hazards: the warden holding the claim, if any (this warden: the hazard is its own)."""
    map_version: int | None = None
    """For maps: the stored version to fetch with the ``map.latest`` / ``map.chunk`` services."""
    late: bool = False
    """Announced long after the robot sent the event (``FLEETBUS_LATE_AFTER_S``, 5 s by default):
    it waited in the robot's outbox, in the queue while the workers were down, or for the wardens
    to localise. The event keeps its original times (``sent_at``, a hazard's ``detected_at``)."""
