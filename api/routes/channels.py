"""Mounts and the channel log: who controls which robot, and whether the broker agrees."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import BindingReportOut, ChannelChangeOut, MountIn, MountOut
from fleetbus.api.openapi import refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.channels import OPERATING, UNMOUNTERS
from fleetbus.api.services.errors import Conflict, NotFound
from fleetbus.schemas.roles import UserRole

router = APIRouter(tags=["channels"])
R = UserRole
Operator = Annotated[User, Depends(require_role(*OPERATING))]
Unmounter = Annotated[User, Depends(require_role(*UNMOUNTERS))]
Watcher = Annotated[User, Depends(require_role(R.OPERATOR, R.SUPERVISOR, R.ADMIN))]
Overseer = Annotated[User, Depends(require_role(R.SUPERVISOR, R.ADMIN))]


@router.post("/mounts", response_model=MountOut, status_code=201, responses=refusals(NotFound, Conflict))
async def mount(body: MountIn, user: Operator, svc: ServiceDep) -> MountOut:
    """Take control of a robot for a mission: its data reaches the operator's stream, the operator's
    commands reach it. Refused (409) when the robot or the operator is booked by another mission."""
    return MountOut.of(await svc.channels.mount(user, body.robot, body.mission_id))


@router.get("/mounts", response_model=list[MountOut])
async def mounts(user: Watcher, svc: ServiceDep) -> list[MountOut]:
    """An operator's own mounts; every mount for supervisors and admins."""
    operator = user.name if user.role is R.OPERATOR else None
    return [MountOut.of(m) for m in await svc.channels.mounts(operator=operator)]


@router.delete("/mounts/{robot}", response_model=MountOut)
async def unmount(robot: str, user: Unmounter, svc: ServiceDep) -> MountOut:
    """Give the robot up; a supervisor may force the unmount of anyone's robot."""
    return MountOut.of(await svc.channels.unmount(user, robot))


@router.get("/channels/changes", response_model=list[ChannelChangeOut])
async def changes(
    user: Overseer,
    svc: ServiceDep,
    mission_id: str | None = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 200,
) -> list[ChannelChangeOut]:
    """Every mount, unmount, check-in and check-out: who, what, when (oldest first)."""
    return [ChannelChangeOut.of(c) for c in await svc.channels.changes(mission_id, limit)]


@router.get("/channels/bindings", response_model=BindingReportOut)
async def bindings(user: Overseer, svc: ServiceDep) -> BindingReportOut:
    """The broker's mount bindings (management API) against the mounts the service recorded."""
    return BindingReportOut.of(await svc.channels.verify())


@router.post("/channels/bindings/repair", response_model=BindingReportOut)
async def repair(user: Overseer, svc: ServiceDep) -> BindingReportOut:
    """Make the broker's mount bindings what the service recorded (after a crash mid-change)."""
    return BindingReportOut.of(await svc.channels.repair(user))
