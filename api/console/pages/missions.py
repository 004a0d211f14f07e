"""Missions: the list and each mission's detail with its state machine (a new one:
:mod:`.new_mission`).

Everything a button does goes through the services the HTTP API calls (``svc.missions``,
``svc.channels``), so the rules are theirs: the role that may take each step is the use case's
machine's (:mod:`fleetbus.schemas.use_cases`), who may mount, unmount and check in is the channels
service's. A button is shown only to the roles it admits; a refusal shows its reason with the
service's status (403 for a role that may not, 409 for a state that does not allow it).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api.console.live import Shared, live_stream
from fleetbus.api.console.pages import mission_detail
from fleetbus.api.console.pages.mission_detail import thread_fragment
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import MISSIONS
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.channels import OPERATING, UNMOUNTERS, may_unmount
from fleetbus.api.services.errors import Conflict, ServiceRefusal
from fleetbus.api.services.mission_comments import COMMENT_MAX, may_comment
from fleetbus.api.services.missions import AUTHORS, MOVERS, may_see
from fleetbus.api.services.stored_events import EventRecord
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import MISSION_DATA_READERS
from fleetbus.schemas.use_cases import CHECK_IN_STATES, USE_CASES, machine_for

router = APIRouter()
router.include_router(mission_detail.router)  # the mission page's map, stream and discussion
Viewer = Annotated[User, Depends(Allowed.page(MISSIONS))]
Mover = Annotated[User, Depends(Allowed(MOVERS, "the mission state buttons"))]
Mounter = Annotated[User, Depends(Allowed(OPERATING, "mounting robots and checking in"))]
Unmounter = Annotated[User, Depends(Allowed(UNMOUNTERS, "unmounting robots"))]

#: What a redirect after a button says was done (a fixed text: nothing from the address is shown).
DONE = {
    "created": "Mission created.",
    "moved": "The mission took the step.",
    "mounted": "Robot mounted.",
    "unmounted": "Robot unmounted.",
    "checked-in": "Checked in: the data of the robots you mounted for this mission is recorded under it.",
    "checked-out": "Checked out.",
    "commented": "Comment added.",
}


def _service(request: Request) -> Service:
    return request.app.state.service


class MissionRows:
    """Every mission's row of the list, newest first, read at most every half second however
    many lists are open (one per API process); each page keeps the rows its user may see."""

    def __init__(self, service: Service) -> None:
        self._service = service
        self._rows = Shared(self._render)
        self._owners: list[str] = []

    async def _render(self) -> list[str]:
        found = list(reversed(await self._service.missions.every()))
        self._owners = [mission.owner for mission in found]
        return [fragment("missions/row.html", mission=mission) for mission in found]

    async def visible_to(self, user: User) -> list[str]:
        rows = await self._rows()
        owners = self._owners  # of the render that made these rows (no await in between)
        return [row for row, owner in zip(rows, owners, strict=True) if may_see(user, owner)]


def mission_rows(request: Request) -> MissionRows:
    state = request.app.state
    if getattr(state, "mission_rows", None) is None:
        state.mission_rows = MissionRows(state.service)
    return state.mission_rows


Rows = Annotated[MissionRows, Depends(mission_rows)]


@dataclass
class MissionList:
    """One open list's live view: its user's rows, as one fragment (the list's body)."""

    rows: MissionRows
    user: User

    async def snapshot(self) -> list[str]:
        return [fragment("missions/rows.html", rows=await self.rows.visible_to(self.user))]

    async def events(self, records: list[EventRecord]) -> list[str]:
        return []  # missions change through the service, not the robots' events: each tick shows them


@router.get("/console/missions", response_class=HTMLResponse)
async def missions(request: Request, user: Viewer, rows: Rows) -> Response:
    found = await _service(request).missions.visible(user)
    states = {state for machine in USE_CASES.values() for state in machine.states}
    return render(
        request,
        "missions/list.html",
        user,
        MISSIONS,
        cursor=request.app.state.feed.cursor,
        rows=fragment("missions/rows.html", rows=await rows.visible_to(user)),
        states=sorted(states, key=lambda state: state.rank),
        use_cases=list(USE_CASES),
        clients=sorted({mission.owner for mission in found}),
        may_create=user.role in AUTHORS,
        done=DONE.get(request.query_params.get("done", "")),
    )


@router.get("/console/stream/missions")
async def missions_stream(request: Request, user: Viewer, rows: Rows) -> Response:
    return live_stream(MissionList(rows, user), request.app.state.feed, request)


# --- one mission --------------------------------------------------------------------------------


async def show_detail(
    request: Request,
    user: User,
    mission_id: str,
    problem: str | None = None,
    status: int = 200,
    comment: str = "",
) -> Response:
    """The mission's page; with ``problem``, the reason an action was refused (and, for a
    comment, its text, to be sent again)."""
    svc = _service(request)
    try:
        detail = await svc.missions.detail(user, mission_id)
    except ServiceRefusal as refused:
        return render(
            request, "missions/missing.html", user, MISSIONS, refused.status, problem=refused.detail
        )
    mission, mounts, check_ins = detail.mission, detail.mounts, detail.check_ins
    machine = machine_for(mission.use_case)
    operating = user.role in OPERATING
    team, robots = await svc.channels.mountable() if operating else (0, [])
    return render(
        request,
        "missions/detail.html",
        user,
        MISSIONS,
        status_code=status,
        mission=mission,
        plan=MissionPlan.model_validate(mission.plan),
        machine=machine,
        steps=machine.steps_from(mission.state),
        role=user.role,
        history=detail.history,
        mounts=mounts,
        check_ins=[(c, [m.robot for m in mounts if m.operator == c.operator]) for c in check_ins],
        may_mount=operating and machine.mountable(mission.state),
        unmountable={m.robot for m in mounts if may_unmount(user, m)},
        may_check_in=operating
        and mission.state in CHECK_IN_STATES
        and all(c.operator != user.name for c in check_ins),
        may_check_out=operating and any(c.operator == user.name for c in check_ins),
        robots=robots,
        team_size=team,
        cursor=request.app.state.feed.cursor,
        thread=await thread_fragment(svc, user, mission_id),
        may_comment=may_comment(user, mission),
        may_read_data=user.role in MISSION_DATA_READERS,
        comment=comment,
        comment_max=COMMENT_MAX,
        points_limit=svc.settings.console_mission_points,
        problem=problem,
        done=DONE.get(request.query_params.get("done", "")) if problem is None else None,
    )


@router.get("/console/missions/{mission_id}", response_class=HTMLResponse)
async def mission(request: Request, user: Viewer, mission_id: str) -> Response:
    return await show_detail(request, user, mission_id)


async def _act(
    request: Request, user: User, mission_id: str, work: Callable[[], Awaitable[object]], done: str
) -> Response:
    """Do ``work`` (a service's action), then back to the mission saying ``done``; or the mission
    with the service's reason, and its status."""
    try:
        await work()
    except ServiceRefusal as refused:
        return await show_detail(request, user, mission_id, refused.detail, refused.status)
    return RedirectResponse(f"/console/missions/{mission_id}?done={done}", status_code=303)


@router.post("/console/missions/{mission_id}/transitions", response_class=HTMLResponse)
async def transition(
    request: Request,
    user: Mover,
    mission_id: str,
    to: Annotated[MissionState, Form()],
    note: Annotated[str, Form(max_length=500)] = "",
) -> Response:
    work = _service(request).missions.transition
    return await _act(request, user, mission_id, lambda: work(user, mission_id, to, note), "moved")


@router.post("/console/missions/{mission_id}/mounts", response_class=HTMLResponse)
async def mount(request: Request, user: Mounter, mission_id: str, robot: Annotated[str, Form()]) -> Response:
    work = _service(request).channels.mount
    return await _act(request, user, mission_id, lambda: work(user, robot, mission_id), "mounted")


@router.post("/console/missions/{mission_id}/unmount", response_class=HTMLResponse)
async def unmount(
    request: Request, user: Unmounter, mission_id: str, robot: Annotated[str, Form()]
) -> Response:
    svc = _service(request)

    async def work() -> object:
        if not await svc.channels.mounts(robot=robot, mission_id=mission_id):
            raise Conflict(f"robot {robot} is not mounted for mission {mission_id}")
        return await svc.channels.unmount(user, robot)

    return await _act(request, user, mission_id, work, "unmounted")


@router.post("/console/missions/{mission_id}/check-in", response_class=HTMLResponse)
async def check_in(request: Request, user: Mounter, mission_id: str) -> Response:
    work = _service(request).channels.check_in
    return await _act(request, user, mission_id, lambda: work(user, mission_id), "checked-in")


@router.post("/console/missions/{mission_id}/check-out", response_class=HTMLResponse)
async def check_out(request: Request, user: Mounter, mission_id: str) -> Response:
    work = _service(request).channels.check_out
    return await _act(request, user, mission_id, lambda: work(user, mission_id), "checked-out")
