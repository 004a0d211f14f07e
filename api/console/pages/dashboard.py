"""The dashboard: the team (a row per robot), the hazards by state, the newest events, live."""

from __future__ import annotations

from collections import Counter
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse, Response

from fleetbus.api.console.feed import Feed
from fleetbus.api.console.live import Shared, live_stream
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import DASHBOARD
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.service import Service
from fleetbus.workers.store.base import EventQuery, EventRecord
from fleetbus.workers.store.hazards import HazardState
from fleetbus.workers.store.users import User

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(DASHBOARD))]


class DashboardView:
    """What every open dashboard shows live; one per API process, shared by all of them."""

    def __init__(self, service: Service, feed: Feed) -> None:
        self._service = service
        self._feed = feed
        self.snapshot = Shared(self._render)
        self.recent_limit = service.settings.console_recent_events

    async def _render(self) -> list[str]:
        team = await self._service.team.view()
        hazards = await self._service.repositories.hazards.open_hazards(None)
        by_state = Counter(hazard.state for hazard in hazards)
        return [
            fragment("dashboard/team.html", team=team),
            fragment("dashboard/hazards.html", states=list(HazardState), by_state=by_state),
            fragment("dashboard/feed.html", feed=self._feed),
        ]

    async def events(self, records: list[EventRecord]) -> list[str]:
        return [fragment("dashboard/event.html", event=record) for record in records[-self.recent_limit :]]

    async def newest(self) -> list[str]:
        """The newest events, for the page as first rendered (the stream adds the later ones)."""
        query = EventQuery(limit=self.recent_limit, newest_first=True)
        found = await self._service.repositories.events.find_events(query)
        return [fragment("dashboard/event.html", event=record) for record in found]


def dashboard_view(request: Request) -> DashboardView:
    state = request.app.state
    if getattr(state, "dashboard", None) is None:
        state.dashboard = DashboardView(state.service, state.feed)
    return state.dashboard


View = Annotated[DashboardView, Depends(dashboard_view)]


@router.get("/console/", response_class=HTMLResponse)
async def dashboard(request: Request, user: Viewer, view: View) -> Response:
    return render(
        request,
        "dashboard/page.html",
        user,
        DASHBOARD,
        cursor=request.app.state.feed.cursor,
        fragments=await view.snapshot(),
        events=await view.newest(),
        recent_limit=view.recent_limit,
    )


@router.get("/console/stream/dashboard")
async def dashboard_stream(request: Request, user: Viewer, view: View) -> Response:
    return live_stream(view, request.app.state.feed, request)
