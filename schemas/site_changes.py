"""What central sends a site over its downlink: the accounts of the site's robots, and the
team's missions as central's store has them, and each new map central stores that a robot of
another site (or of central) made. A message is one change; its ``change`` field says
which kind (:data:`SiteChange`, parsed by :func:`parse_site_change`).

The password travels as RabbitMQ's own salted hash (``password_hash`` and ``hashing_algorithm``
as the management API shows them), so a robot logs in to its site with the password central gave
it, and the password itself never leaves central.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from fleetbus.schemas.mission_states import MissionState
from fleetbus.schemas.routing import RobotKind

SITE_CHANGE_TYPE = "fleetbus.site-change"


class RobotAccount(BaseModel):
    model_config = ConfigDict(extra="forbid")

    change: Literal["account"] = "account"
    name: str
    kind: RobotKind | None
    password_hash: str
    hashing_algorithm: str


class MissionChange(BaseModel):
    """A mission as central's store has it; ``updated_at`` orders the versions of one mission
    (the site keeps the newest it was sent, whatever order they arrive in)."""

    model_config = ConfigDict(extra="forbid")

    change: Literal["mission"] = "mission"
    mission_id: str
    number: int
    use_case: str
    title: str
    owner: str
    state: MissionState
    plan: dict[str, Any]
    created_at: datetime
    updated_at: datetime


class MapChange(BaseModel):
    """A map version central stored: the map event it came from (``robot_id``, ``epoch``,
    ``seq``: the site stores it once however often it arrives) and its whole PGM (base64 in JSON)."""

    model_config = ConfigDict(extra="forbid", ser_json_bytes="base64", val_json_bytes="base64")

    change: Literal["map"] = "map"
    robot_id: str
    epoch: str
    seq: int
    metadata: dict[str, Any]
    created_at: datetime
    sha256: str
    pgm: bytes


SiteChange = Annotated[RobotAccount | MissionChange | MapChange, Field(discriminator="change")]
AnySiteChange = RobotAccount | MissionChange | MapChange
_SITE_CHANGE: TypeAdapter[AnySiteChange] = TypeAdapter(SiteChange)


def parse_site_change(body: bytes) -> AnySiteChange:
    """One downlink message; pydantic's ValidationError when it is no change this version knows."""
    return _SITE_CHANGE.validate_json(body)
