"""A new mission: the form (its plan drawn on the team's map, or typed), a summary to check, and
only on Confirm the mission.

The form's text fields are the plan, with or without JavaScript: ``plan_map.js`` draws the
geofence and the points of interest on the newest stored version of the team's map and writes
them into those fields. Submitting shows the summary and stores nothing; Confirm sends the same
fields again, which are checked again and created through ``svc.missions``, as the HTTP API and
the CLI create them; Back takes them to the form. A plan that does not hold together is refused
with the model's reasons (those the HTTP API gives) and nothing is stored.

Authors (clients and planners) may not open the live map, which shows where the team is; this
form shows them the image of the map's newest version only, served here (older versions are
refused: :mod:`fleetbus.api.services.maps`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from pydantic import ValidationError

from fleetbus.api.console.map_image import Frame
from fleetbus.api.console.pages.live_map import View, png_answer
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import MISSIONS
from fleetbus.api.console.templating import render
from fleetbus.api.parameters import MapVersionNumber
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.maps import MapVersion
from fleetbus.api.services.missions import AUTHORS, use_case_refusal
from fleetbus.schemas.missions import MissionPlan
from fleetbus.schemas.use_cases import USE_CASES, InvalidTransition, machine_for

router = APIRouter()
Author = Annotated[User, Depends(Allowed(AUTHORS, "the new mission form"))]
#: Where the form shows the newest stored version of the team's map (``{}``: the version).
MAP_IMAGE = "/console/missions/new/map/{}.png"


@dataclass
class PlanForm:
    """The plan as the form takes it: one vertex or point of interest a line."""

    geofence: str = ""
    points_of_interest: str = ""
    risk_level: str = ""
    risk_summary: str = ""
    mitigations: str = ""

    def plan(self) -> MissionPlan:
        """The plan, or ValueError naming every line or field that is wrong."""
        problems: list[str] = []
        plan: dict[str, Any] = {}
        vertices = [_numbers(line, 2, f"geofence line {n}", problems) for n, line in _lines(self.geofence)]
        if vertices:
            plan["geofence"] = {"polygon": [{"x": v[0], "y": v[1]} for v in vertices if v]}
        plan["points_of_interest"] = [
            poi for n, line in _lines(self.points_of_interest) if (poi := _poi(n, line, problems))
        ]
        if self.risk_level or self.risk_summary.strip():
            plan["risk_assessment"] = {
                "level": self.risk_level,
                "summary": self.risk_summary.strip(),
                "mitigations": [line for _, line in _lines(self.mitigations)],
            }
        if problems:
            raise ValueError("; ".join(problems))
        try:
            return MissionPlan.model_validate(plan)
        except ValidationError as error:
            raise ValueError(_readable(error)) from None


def _lines(text: str) -> list[tuple[int, str]]:
    return [(n, line.strip()) for n, line in enumerate(text.splitlines(), 1) if line.strip()]


def _numbers(text: str, count: int, where: str, problems: list[str]) -> list[float] | None:
    parts = text.replace(",", " ").split()
    try:
        if len(parts) != count:
            raise ValueError
        return [float(part) for part in parts]
    except ValueError:
        problems.append(f"{where}: expected {count} numbers, got {text!r}")
        return None


def _poi(number: int, line: str, problems: list[str]) -> dict[str, Any] | None:
    name, *rest = [part.strip() for part in line.split(",", 3)]
    where = _numbers(" ".join(rest[:2]), 2, f"point of interest line {number} ({name})", problems)
    if where is None:
        return None
    return {"name": name, "x": where[0], "y": where[1], "note": rest[2] if len(rest) > 2 else ""}


def _readable(error: ValidationError) -> str:
    """pydantic's errors as one line: where, then what."""
    parts = []
    for item in error.errors():
        where = ".".join(str(step) for step in item["loc"])
        message = str(item["msg"]).removeprefix("Value error, ")
        parts.append(f"{where}: {message}" if where else message)
    return "; ".join(parts)


@dataclass
class Draft:
    """A new mission as the form sends it (the form, the summary's Confirm and Back alike)."""

    title: str = ""
    use_case: str = ""
    form: PlanForm = field(default_factory=PlanForm)

    def checked(self) -> MissionPlan:
        """The plan, or ValueError saying what is wrong, as the form shows it."""
        if not self.title.strip():
            raise ValueError("the mission needs a title")
        try:
            machine_for(self.use_case)
        except InvalidTransition as error:
            raise ValueError(str(error)) from None
        try:
            return self.form.plan()
        except ValueError as problem:
            raise ValueError(f"the plan is not valid: {problem}") from None


def posted(
    title: Annotated[str, Form()] = "",
    use_case: Annotated[str, Form()] = "",
    geofence: Annotated[str, Form()] = "",
    points_of_interest: Annotated[str, Form()] = "",
    risk_level: Annotated[str, Form()] = "",
    risk_summary: Annotated[str, Form()] = "",
    mitigations: Annotated[str, Form()] = "",
) -> Draft:
    plan = PlanForm(geofence, points_of_interest, risk_level, risk_summary, mitigations)
    return Draft(title, use_case, plan)


Posted = Annotated[Draft, Depends(posted)]


async def _newest_frame(view: View) -> Frame | None:
    """The newest stored map version's frame, for the form's map; None before any is stored."""
    found = await view.stored(None)
    return await view.images.frame(found) if isinstance(found, MapVersion) else None


async def _form(
    request: Request, user: User, view: View, draft: Draft, status: int = 200, problem: str | None = None
) -> Response:
    frame = await _newest_frame(view)
    return render(
        request,
        "missions/new.html",
        user,
        MISSIONS,
        status_code=status,
        use_cases=[m for m in USE_CASES.values() if use_case_refusal(user, m.use_case) is None],
        draft=draft,
        frame=frame,
        image=MAP_IMAGE.format(frame.version.version) if frame else None,
        problem=problem,
    )


@router.get("/console/missions/new", response_class=HTMLResponse)
async def new_mission(request: Request, user: Author, view: View) -> Response:
    return await _form(request, user, view, Draft())


@router.post("/console/missions/new", response_class=HTMLResponse)
async def edit_again(request: Request, user: Author, view: View, draft: Posted) -> Response:
    """Back from the summary: the form with what it held."""
    return await _form(request, user, view, draft)


@router.get("/console/missions/new/map/{version}.png")
async def map_image(user: Author, view: View, version: MapVersionNumber) -> Response:
    """The newest version's image only (:mod:`fleetbus.api.services.maps`): what the form draws on."""
    return await png_answer(view, user, version)


@router.post("/console/missions/summary", response_class=HTMLResponse)
async def summary(request: Request, user: Author, view: View, draft: Posted) -> Response:
    """What Confirm will create, on the map and as a list; nothing is stored yet."""
    try:
        plan = draft.checked()
    except ValueError as problem:
        return await _form(request, user, view, draft, 422, str(problem))
    frame = await _newest_frame(view)
    return render(
        request,
        "missions/summary.html",
        user,
        MISSIONS,
        draft=draft,
        plan=plan,
        machine=USE_CASES[draft.use_case],
        frame=frame,
        image=MAP_IMAGE.format(frame.version.version) if frame else None,
    )


@router.post("/console/missions", response_class=HTMLResponse)
async def create_mission(request: Request, user: Author, view: View, draft: Posted) -> Response:
    """Confirm: the mission created, checked again (the fields came back from the browser)."""
    try:
        plan = draft.checked()
    except ValueError as problem:
        return await _form(request, user, view, draft, 422, str(problem))
    service: Service = request.app.state.service
    try:
        mission = await service.missions.create(user, draft.use_case, draft.title.strip(), plan)
    except ServiceRefusal as refused:
        return await _form(request, user, view, draft, refused.status, refused.detail)
    return RedirectResponse(f"/console/missions/{mission.mission_id}?done=created", status_code=303)
