"""What a broker account is for; it decides the resources the account owns
(see ``fleetbus.broker.topology``)."""

from __future__ import annotations

from enum import Enum


class Role(str, Enum):
    ROBOT = "robot"
    """Publishes events and beacons, receives notifications and the commands of who mounted it."""
    OPERATOR = "operator"
    """Receives every notification; follows mounted robots in its stream and commands them."""
    SERVICE = "service"
    """The workers' own account."""
    USER = "user"
    """Any other person (client, planner, admin, guest): an inbox, nothing bound to it by default."""


#: Management UI access: operators trace messages there; others need none.
ROLE_TAGS = {Role.ROBOT: "", Role.OPERATOR: "management", Role.SERVICE: "", Role.USER: ""}
