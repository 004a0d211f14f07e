"""Missions: create, plan, move through the use case's states, check in and out, recorded events."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import (
    CheckInOut,
    CheckOutOut,
    EventOut,
    MissionCreate,
    MissionDetail,
    MissionOut,
    MountOut,
    StateChangeOut,
    TransitionIn,
    UseCaseOut,
)
from fleetbus.api.openapi import refusal_meaning, refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.channels import OPERATING
from fleetbus.api.services.errors import Conflict
from fleetbus.api.services.missions import AUTHORS, MOVERS
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import ACTIVE_ROLES, MISSION_DATA_READERS, UserRole
from fleetbus.schemas.use_cases import USE_CASES

router = APIRouter(tags=["missions"])
R = UserRole
Anyone = Annotated[User, Depends(require_role(*ACTIVE_ROLES))]
Reader = Annotated[
    User, Depends(require_role(R.ADMIN, R.CLIENT, R.PLANNER, R.SUPERVISOR, R.OPERATOR, R.GUEST))
]
DataReader = Annotated[User, Depends(require_role(*MISSION_DATA_READERS))]
Author = Annotated[User, Depends(require_role(*AUTHORS))]
Mover = Annotated[User, Depends(require_role(*MOVERS))]
Operator = Annotated[User, Depends(require_role(*OPERATING))]


@router.get("/use-cases", response_model=list[UseCaseOut])
async def use_cases(user: Anyone) -> list[UseCaseOut]:
    """Each use case's states and steps: who may take which step."""
    return [UseCaseOut.of(machine) for machine in USE_CASES.values()]


@router.post(
    "/missions",
    response_model=MissionOut,
    status_code=201,
    responses=refusal_meaning(
        403,
        "The caller's role may not create missions, or the caller may not create missions of this "
        "use case (an admin sets each user's: `PUT /users/{name}/use-cases`)",
    ),
)
async def create_mission(body: MissionCreate, user: Author, svc: ServiceDep) -> MissionOut:
    """A new mission, in planning, of a use case the caller is allowed (every one unless an admin
    restricted them)."""
    return MissionOut.of(await svc.missions.create(user, body.use_case, body.title, body.plan))


@router.get("/missions", response_model=list[MissionOut])
async def list_missions(user: Reader, svc: ServiceDep, state: MissionState | None = None) -> list[MissionOut]:
    """Every mission; a client sees its own."""
    return [MissionOut.of(m) for m in await svc.missions.visible(user, state)]


@router.get("/missions/{mission_id}", response_model=MissionDetail)
async def get_mission(mission_id: str, user: Reader, svc: ServiceDep) -> MissionDetail:
    detail = await svc.missions.detail(user, mission_id)
    return MissionDetail(
        **MissionOut.of(detail.mission).model_dump(),
        mounts=[MountOut.of(m) for m in detail.mounts],
        checked_in=[CheckInOut.of(c) for c in detail.check_ins],
        history=[StateChangeOut.of(c) for c in detail.history],
    )


@router.put("/missions/{mission_id}/plan", response_model=MissionOut, responses=refusals(Conflict))
async def edit_plan(mission_id: str, plan: MissionPlan, user: Author, svc: ServiceDep) -> MissionOut:
    """Replace the plan (geofence, points of interest, itinerary, risk assessment) while in planning."""
    return MissionOut.of(await svc.missions.edit_plan(user, mission_id, plan))


@router.post("/missions/{mission_id}/transitions", response_model=MissionOut, responses=refusals(Conflict))
async def transition(mission_id: str, body: TransitionIn, user: Mover, svc: ServiceDep) -> MissionOut:
    """Take one step of the use case's state machine (409 names the current state and the allowed ones)."""
    return MissionOut.of(await svc.missions.transition(user, mission_id, body.to, body.note))


@router.get("/missions/{mission_id}/events", response_model=list[EventOut])
async def mission_events(
    mission_id: str,
    user: DataReader,
    svc: ServiceDep,
    type: str | None = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
) -> list[EventOut]:
    """The events recorded under the mission, each with its provenance."""
    records = await svc.mission_events.recorded(user, mission_id, type, limit)
    return [EventOut.of(r) for r in records]


@router.post("/missions/{mission_id}/check-in", response_model=CheckInOut, responses=refusals(Conflict))
async def check_in(mission_id: str, user: Operator, svc: ServiceDep) -> CheckInOut:
    """From now on, the data of the robots this operator mounted for the mission is recorded under it."""
    return CheckInOut.of(await svc.channels.check_in(user, mission_id))


@router.post("/missions/{mission_id}/check-out", response_model=CheckOutOut, responses=refusals(Conflict))
async def check_out(mission_id: str, user: Operator, svc: ServiceDep) -> CheckOutOut:
    """Stop recording; when the last operator checks out, the mission moves to reviewing."""
    return CheckOutOut.of(await svc.channels.check_out(user, mission_id))
