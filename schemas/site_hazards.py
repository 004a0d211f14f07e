"""What a site tells central of each of its hazards: its state there, whenever it changed.

The site is the authority for its team's hazards (its wardens claim, reach and clear them there).
Each message is one hazard as the site's store has it, with its ``version``, which grows with each
change at the site: central applies a message only when it is newer than what it has, so a
repeated or overtaken one changes nothing. The hazard event travels with its state, so central
can show the hazard even before the event itself came up the uplink.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from fleetbus.schemas.envelope import EVENT_ADAPTER, HazardEvent

SITE_HAZARD_TYPE = "fleetbus.site-hazard"


class SiteHazardState(BaseModel):
    model_config = ConfigDict(extra="forbid")

    mission_id: str = Field(min_length=1)
    hazard_id: int = Field(ge=1)
    """The hazard's id at the site (central gives it one of its own in the mission)."""
    robot_id: str
    epoch: str
    seq: int = Field(ge=0)
    event: dict[str, Any]
    """The hazard event as its robot sent it."""
    state: Literal["held", "announced", "claimed", "reached", "cleared"]
    received_at: datetime
    announced_at: datetime | None = None
    claimed_by: str | None = None
    claimed_at: datetime | None = None
    reached_at: datetime | None = None
    cleared_at: datetime | None = None
    held_reason: str | None = None
    version: int = Field(ge=0)

    @model_validator(mode="after")
    def _of_its_event(self) -> SiteHazardState:
        """The event is a hazard event, and the one the message names (robot, epoch, sequence)."""
        event = EVENT_ADAPTER.validate_python(self.event)
        if not isinstance(event, HazardEvent):
            raise ValueError(f"the event is a {event.type.value} event, not a hazard")
        if (event.robot_id, event.epoch, event.seq) != (self.robot_id, self.epoch, self.seq):
            raise ValueError("the event is not the one the message names (robot, epoch, sequence)")
        return self
