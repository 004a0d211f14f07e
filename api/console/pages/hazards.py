"""Hazards: every hazard, cleared ones too, newest first, each with its history (detected, held and
why, announced, claimed by whom, reached, cleared), and the wardens the gate follows; live.

Supervisors and operators (the roles that take wardens out of service through the API) take a
hazard's step for a warden (:mod:`fleetbus.workers.hazard_steps`) and take wardens out of service
and back (``svc.team.set_in_service``). Their buttons post with htmx; the answer is a notice and the
changed part of the page, which the live stream then keeps current.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Query, Request
from fastapi.responses import HTMLResponse, Response

from fleetbus.api.console.live import Shared, live_stream
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import HAZARDS
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.parameters import HazardId
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.hazards import Hazard, HazardState
from fleetbus.api.services.stored_events import EventRecord
from fleetbus.api.services.team import DISPATCHERS, TeamView
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.hazard_steps import steps_from
from fleetbus.workers.team import why_held

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(HAZARDS))]
Dispatcher = Annotated[User, Depends(Allowed(DISPATCHERS, "the buttons that act for wardens"))]
TEAM_CHANGES = {"out": False, "in": True}
#: The last page a listing may ask for: far beyond any registry, and within the store's integers.
MAX_PAGE = 1_000_000


@dataclass(frozen=True)
class Card:
    """One hazard as the page shows it."""

    hazard: Hazard
    why_held: str
    description: str
    where: str
    detected_at: datetime | None

    @property
    def held_for(self) -> str:
        """How long it was held before its announcement: ``3 s``, ``2 min``."""
        if self.hazard.announced_at is None:
            return ""
        seconds = max(0, int((self.hazard.announced_at - self.hazard.received_at).total_seconds()))
        return f"{seconds} s" if seconds < 120 else f"{seconds // 60} min"

    @property
    def element_id(self) -> str:
        return f"hazard-{self.hazard.mission_id}-{self.hazard.hazard_id}"

    @classmethod
    def of(cls, hazard: Hazard, team: TeamView, now: datetime) -> Card:
        body: dict[str, Any] = hazard.event.get("body", {})
        pose = body.get("pose") or {}
        seen = {member.robot.name: member.last_seen for member in team.members}
        detected = body.get("detected_at")
        return cls(
            hazard,
            why_held(hazard, team.gate, seen, now),
            str(body.get("description", "")),
            f"({pose.get('x', 0):g}, {pose.get('y', 0):g})" if pose else "",
            datetime.fromisoformat(detected) if isinstance(detected, str) else None,
        )


@dataclass(frozen=True)
class Listing:
    cards: list[Card]
    more: bool
    """There are older hazards than these."""
    team: TeamView


async def listing(service: Service, page: int, size: int) -> Listing:
    """Page ``page`` (from 1) of every hazard, newest first, and the team that explains them."""
    found = await service.hazards.recent(size + 1, (page - 1) * size)
    team = await service.team.view()
    now = datetime.now(timezone.utc)
    return Listing([Card.of(hazard, team, now) for hazard in found[:size]], len(found) > size, team)


def _wardens(team: TeamView) -> list[str]:
    """The wardens a hazard may be given to: in service (one out of service is sent nothing)."""
    return [member.robot.name for member in team.members if member.counts_for_gate]


def card_html(card: Card, team: TeamView, acts: bool, oob: bool = False) -> str:
    return fragment(
        "hazards/card.html",
        card=card,
        steps=steps_from(card.hazard) if acts else [],
        wardens=_wardens(team),
        held=HazardState.HELD,
        stage=list(HazardState).index(card.hazard.state),
        oob=oob,
    )


def team_html(team: TeamView, acts: bool, oob: bool = False) -> str:
    wardens = [member for member in team.members if member.robot.kind == RobotKind.WARDEN.value]
    return fragment("hazards/team.html", team=team, wardens=wardens, acts=acts, oob=oob)


def empty_html(count: int) -> str:
    return fragment("hazards/empty.html", count=count)


class HazardsView:
    """What the newest page of hazards shows live, for viewers who act (``acts``) or only watch;
    one of each per API process, shared by every open page."""

    def __init__(self, service: Service, acts: bool) -> None:
        self._service = service
        self._acts = acts
        self.size = service.settings.console_hazards_page
        self.snapshot = Shared(self._render)

    async def _render(self) -> list[str]:
        found = await listing(self._service, 1, self.size)
        # oldest first: a card not on the page yet goes on top of the list, so the newest ends first
        cards = [card_html(card, found.team, self._acts) for card in reversed(found.cards)]
        return [team_html(found.team, self._acts), empty_html(len(found.cards)), *cards]

    async def events(self, records: list[EventRecord]) -> list[str]:
        return []  # hazards are registered after their events are stored: the snapshot shows them


def acts(user: User) -> bool:
    return user.role in DISPATCHERS


def hazards_view(request: Request, user: Viewer) -> HazardsView:
    state = request.app.state
    views = getattr(state, "hazards_views", None)
    if views is None:
        views = state.hazards_views = {
            True: HazardsView(state.service, True),
            False: HazardsView(state.service, False),
        }
    return views[acts(user)]


View = Annotated[HazardsView, Depends(hazards_view)]


@router.get("/console/hazards", response_class=HTMLResponse)
async def hazards(
    request: Request, user: Viewer, view: View, page: Annotated[int, Query(ge=1, le=MAX_PAGE)] = 1
) -> Response:
    found = await listing(request.app.state.service, page, view.size)
    may_act = acts(user)
    return render(
        request,
        "hazards/page.html",
        user,
        HAZARDS,
        live=page == 1,
        cursor=request.app.state.feed.cursor,
        team=team_html(found.team, may_act),
        empty=empty_html(len(found.cards)),
        cards=[card_html(card, found.team, may_act) for card in found.cards],
        page_number=page,
        more=found.more,
        size=view.size,
    )


@router.get("/console/stream/hazards")
async def hazards_stream(request: Request, user: Viewer, view: View) -> Response:
    return live_stream(view, request.app.state.feed, request)


def _notice(text: str, problem: bool, *parts: str) -> HTMLResponse:
    """The answer to a button: what happened (or why not), and the parts of the page it changed."""
    return HTMLResponse("\n".join([fragment("hazards/notice.html", text=text, problem=problem), *parts]))


@router.post("/console/hazards/steps/{mission_id}/{hazard_id}/{step}", response_class=HTMLResponse)
async def take_step(
    request: Request,
    user: Dispatcher,
    mission_id: str,
    hazard_id: HazardId,
    step: str,
    warden: Annotated[str, Form()],
) -> Response:
    service: Service = request.app.state.service
    try:
        taken = await service.hazard_steps.take(mission_id, hazard_id, warden, step, user.name)
    except ServiceRefusal as refused:
        return _notice(refused.detail, True)
    team = await service.team.view()
    card = Card.of(taken.hazard, team, datetime.now(timezone.utc))
    done = f"hazard {hazard_id} ({card.description}): {step} for {warden}"
    if taken.not_told:
        return _notice(f"{done}; {taken.not_told}", True, card_html(card, team, True, oob=True))
    return _notice(f"{done}; {warden} was told", False, card_html(card, team, True, oob=True))


@router.post("/console/hazards/wardens/{robot}/{change}", response_class=HTMLResponse)
async def change_service(request: Request, user: Dispatcher, robot: str, change: str) -> Response:
    service: Service = request.app.state.service
    if change not in TEAM_CHANGES:
        return _notice(f"no team change {change!r}; changes: {', '.join(TEAM_CHANGES)}", True)
    try:
        await service.team.set_in_service(robot, TEAM_CHANGES[change], user.name)
    except ServiceRefusal as refused:
        return _notice(refused.detail, True)
    team = await service.team.view()
    done = "back in service" if TEAM_CHANGES[change] else "out of service"
    return _notice(f"{robot} {done} (by {user.name})", False, team_html(team, True, oob=True))
