"""What central sends a site over its downlink: the accounts of the site's robots (and the removal
of those it no longer has, one by one or as the whole list of its robots), and the
team's missions as central's store has them, and each new map central stores that a robot of
another site (or of central) made. A map larger than one chunk (``MAP_CHUNK_BYTES``) travels as
its chunks (:class:`MapChunk`) followed by its :class:`MapChange`, so no message comes near the
broker's largest (16 MiB by default on RabbitMQ 4). A message is one change; its ``change`` field says
which kind (:data:`SiteChange`, parsed by :func:`parse_site_change`).

Every message about the site's robots carries the ``revision`` of central's list of the site's
robots it was made from (one more at each change of the list): the site applies one about a robot
only if no newer one about that robot was applied, so a message that waited (a ``sites sync``
that read the list before an ``--add``) never undoes a newer change. None: from a central that
numbers no revisions (applied as it comes).

The password travels as RabbitMQ's own salted hash (``password_hash`` and ``hashing_algorithm``
as the management API shows them), so a robot logs in to its site with the password central gave
it, and the password itself never leaves central.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from fleetbus.schemas.mission_states import MissionState
from fleetbus.schemas.routing import RobotKind

SITE_CHANGE_TYPE = "fleetbus.site-change"

Revision = Annotated[int | None, Field(ge=0)]
"""The revision of central's list of the site's robots a message was made from."""


class RobotAccount(BaseModel):
    model_config = ConfigDict(extra="forbid")

    change: Literal["account"] = "account"
    name: str
    kind: RobotKind | None
    password_hash: str
    hashing_algorithm: str
    revision: Revision = None


class RobotAccountRemoved(BaseModel):
    """A robot the site no longer has (removed at central, or taken from the site): the site
    removes its copy of the account, stops forwarding its events and takes it out of its team."""

    model_config = ConfigDict(extra="forbid")

    change: Literal["account_removed"] = "account_removed"
    name: str
    revision: Revision = None


class RobotRoster(BaseModel):
    """Every robot of the site, as central's registry has them (``fleetbus sites sync`` sends it
    after their accounts): the site removes its copies of the accounts central gave it (the robots
    whose events it forwards) that are not named, as it removes one :class:`RobotAccountRemoved`
    names. Robots made at the site alone are not central's to remove."""

    model_config = ConfigDict(extra="forbid")

    change: Literal["robots"] = "robots"
    names: list[str]
    revision: Revision = None


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


class MapChunk(BaseModel):
    """One part of a large map's PGM, sent before its :class:`MapChange`; the site keeps it with
    the map's other parts (``map_id``) until the change commits them."""

    model_config = ConfigDict(extra="forbid", ser_json_bytes="base64", val_json_bytes="base64")

    change: Literal["map_chunk"] = "map_chunk"
    map_id: str = Field(min_length=1, max_length=200)
    index: int = Field(ge=0)
    data: bytes = Field(min_length=1)


class MapChange(BaseModel):
    """A map version central stored: the map event it came from (``robot_id``, ``epoch``,
    ``seq``: the site stores it once however often it arrives) and its whole PGM (base64 in JSON),
    or, for a large map, how many :class:`MapChunk` (``chunks``, under ``map_id``) carried it."""

    model_config = ConfigDict(extra="forbid", ser_json_bytes="base64", val_json_bytes="base64")

    change: Literal["map"] = "map"
    robot_id: str
    epoch: str
    seq: int
    metadata: dict[str, Any]
    created_at: datetime
    sha256: str
    pgm: bytes = b""
    map_id: str | None = Field(None, min_length=1, max_length=200)
    chunks: int = Field(0, ge=0)

    @model_validator(mode="after")
    def _image_inline_or_in_chunks(self) -> MapChange:
        if self.chunks and (self.map_id is None or self.pgm):
            raise ValueError("a map sent in chunks names its map_id and carries no pgm of its own")
        if not self.chunks and (self.map_id is not None or not self.pgm):
            raise ValueError("a map sent whole carries its pgm and no map_id")
        return self


SiteChange = Annotated[
    RobotAccount | RobotAccountRemoved | RobotRoster | MissionChange | MapChunk | MapChange,
    Field(discriminator="change"),
]
AnySiteChange = RobotAccount | RobotAccountRemoved | RobotRoster | MissionChange | MapChunk | MapChange
_SITE_CHANGE: TypeAdapter[AnySiteChange] = TypeAdapter(SiteChange)


def parse_site_change(body: bytes) -> AnySiteChange:
    """One downlink message; pydantic's ValidationError when it is no change this version knows."""
    return _SITE_CHANGE.validate_json(body)
