"""Hazards: every hazard newest first, and the steps an operator takes for a warden."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import HazardOut, HazardStepIn, HazardStepOut
from fleetbus.api.openapi import refusals
from fleetbus.api.parameters import HazardId
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import Conflict
from fleetbus.api.services.hazards import HazardState
from fleetbus.api.services.team import DISPATCHERS
from fleetbus.schemas.roles import WATCHERS

router = APIRouter(tags=["hazards"])
Watcher = Annotated[User, Depends(require_role(*WATCHERS))]
Dispatcher = Annotated[User, Depends(require_role(*DISPATCHERS))]
Step = Literal["claim", "reached", "cleared", "release"]


@router.get("/hazards", response_model=list[HazardOut])
async def list_hazards(
    user: Watcher,
    svc: ServiceDep,
    state: HazardState | None = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[HazardOut]:
    """Every hazard of every mission (or those in ``state``), cleared ones too, newest first."""
    return [HazardOut.of(hazard) for hazard in await svc.hazards.recent(limit, offset, state)]


@router.post(
    "/hazards/{mission_id}/{hazard_id}/{step}", response_model=HazardStepOut, responses=refusals(Conflict)
)
async def take_step(
    mission_id: str, hazard_id: HazardId, step: Step, body: HazardStepIn, user: Dispatcher, svc: ServiceDep
) -> HazardStepOut:
    """Take a hazard's step for a warden, by the rules of the warden's own request (a claim for a
    warden in service; the other steps for the warden holding the claim); the warden is told in
    its inbox. 409 when the hazard, the warden or the team does not allow the step."""
    taken = await svc.hazard_steps.take(mission_id, hazard_id, body.warden, step, user.name)
    return HazardStepOut(
        hazard=HazardOut.of(taken.hazard), warden_told=taken.not_told is None, not_told=taken.not_told
    )
