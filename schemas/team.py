"""What the service layer tells the hazard service when the team changes under it."""

from __future__ import annotations

from enum import Enum

from pydantic import AwareDatetime, BaseModel, ConfigDict

from fleetbus.schemas.identity import RobotId

#: The AMQP ``type`` of a team change, put on the express lane by the default exchange (which no
#: robot may write to: only the administrator and the service's own account can).
TEAM_CHANGE_TYPE = "fleetbus.team-change"


class TeamChangeKind(str, Enum):
    OUT = "out"
    """A warden taken out of service: the gate may open without it."""
    IN = "in"
    """A warden put back in service: it is owed the open hazards it missed."""
    REMOVED = "removed"
    """A warden's account removed: it left the team, and the gate may open without it."""


class TeamChange(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    robot: RobotId
    change: TeamChangeKind
    by: str
    """Who made the change (an API user, or the command line's user)."""
    at: AwareDatetime
