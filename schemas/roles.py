"""The roles of the service layer's users, and what each is for.

A new account is ``inactive`` and may do nothing until an admin gives it a role. The HTTP API
checks the caller's role on every endpoint (``fleetbus.api.auth.require_role``); the broker account each
user also gets is confined to its own name whatever the role.
"""

from __future__ import annotations

from enum import Enum


class UserRole(str, Enum):
    ADMIN = "admin"
    CLIENT = "client"
    PLANNER = "planner"
    SUPERVISOR = "supervisor"
    OPERATOR = "operator"
    ROBOT = "robot"
    GUEST = "guest"
    INACTIVE = "inactive"


ROLE_PURPOSE: dict[UserRole, str] = {
    UserRole.ADMIN: "creates users, sets their roles, sees every account and mission",
    UserRole.CLIENT: "requests missions (use case, geofence, points of interest) and accepts their results",
    UserRole.PLANNER: "plans missions: itinerary, risk assessment; files them",
    UserRole.SUPERVISOR: "approves, starts, interrupts and closes missions; may force an unmount; "
    "takes wardens out of service and back",
    UserRole.OPERATOR: "mounts robots, checks in to missions, follows and commands mounted robots; "
    "takes wardens out of service and back",
    UserRole.ROBOT: "publishes its data; logs in only to fetch its broker credentials",
    UserRole.GUEST: "reads the mission list",
    UserRole.INACTIVE: "nothing (the role of every new account)",
}

#: Every role that may do anything at all.
ACTIVE_ROLES = frozenset(UserRole) - {UserRole.INACTIVE}

#: Who watches the team and its traffic: fault analysis reads every robot's messages.
WATCHERS = frozenset({UserRole.ADMIN, UserRole.SUPERVISOR, UserRole.OPERATOR})
#: Who reads the recording's figures (the performance evaluation, its growth), not its traffic.
EVALUATORS = WATCHERS | {UserRole.PLANNER}
#: Who reads what the robots recorded under a mission (its sensor readings), of a mission it may
#: see: a guest reads the mission list only.
MISSION_DATA_READERS = EVALUATORS | {UserRole.CLIENT}
