"""What central sends a site over its downlink: the accounts of the site's robots.

The password travels as RabbitMQ's own salted hash (``password_hash`` and ``hashing_algorithm``
as the management API shows them), so a robot logs in to its site with the password central gave
it, and the password itself never leaves central.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict

from fleetbus.schemas.routing import RobotKind

SITE_CHANGE_TYPE = "fleetbus.site-change"


class RobotAccount(BaseModel):
    model_config = ConfigDict(extra="forbid")

    change: Literal["account"] = "account"
    name: str
    kind: RobotKind | None
    password_hash: str
    hashing_algorithm: str
