"""The team the hazard gate follows: every robot, and wardens taken out of service and back."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import TeamMemberOut, TeamOut
from fleetbus.api.openapi import refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import BadRequest
from fleetbus.api.services.team import DISPATCHERS
from fleetbus.schemas.roles import WATCHERS, UserRole

router = APIRouter(tags=["team"])
R = UserRole
Watcher = Annotated[User, Depends(require_role(*WATCHERS))]
Dispatcher = Annotated[User, Depends(require_role(*DISPATCHERS))]


@router.get("/team", response_model=TeamOut)
async def team(
    user: Watcher,
    svc: ServiceDep,
    offset: Annotated[int, Query(ge=0, description="skip this many robots (by name)")] = 0,
    limit: Annotated[int | None, Query(ge=1, le=1000, description="at most this many robots")] = None,
) -> TeamOut:
    """The robots of the team, by name (kind, localised, last seen, stale, in service, counts for
    the gate, what its outbox dropped; a page with ``offset`` and ``limit``) and the hazard gate:
    open, or why it holds hazards."""
    return TeamOut.of(await svc.team.view(offset=offset, limit=limit))


@router.post("/team/{robot}/out", response_model=TeamMemberOut, responses=refusals(BadRequest))
async def take_out(robot: str, user: Dispatcher, svc: ServiceDep) -> TeamMemberOut:
    """Take a warden out of service: it no longer holds the hazard gate and is sent no hazards.
    Recorded with who did it and when."""
    await svc.team.set_in_service(robot, False, user.name)
    return TeamMemberOut.of(await svc.team.member(robot))


@router.post("/team/{robot}/in", response_model=TeamMemberOut, responses=refusals(BadRequest))
async def put_back(robot: str, user: Dispatcher, svc: ServiceDep) -> TeamMemberOut:
    """Put a warden back in service: it is sent the open hazards it missed, then counts for the gate."""
    await svc.team.set_in_service(robot, True, user.name)
    return TeamMemberOut.of(await svc.team.member(robot))
