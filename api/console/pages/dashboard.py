"""The dashboard: the signed-in user's own work (:mod:`..my_work`, every role); for those who watch
the team, the team (a row per robot, those that need attention first, bounded), the hazards by
state, the broker's health, the dead letters of the last hour, on central its sites' links, the
newest events; live.

What one refresh costs, whatever the number of open dashboards (they share it, :class:`Shared`)
and of robots: a few store reads (the team, the hazard counts and the newest of each state, the open
sequence gaps, the mounts), bounded however many hazards are open.
Each robot's last-seen time, battery and pose are kept in memory from the live feed
(:mod:`..latest`), and the broker is polled in the background at most every
``console_broker_poll_s`` (:mod:`..broker_health`).
"""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from datetime import datetime, timezone
from typing import Annotated

import httpx
from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.broker_health import BrokerWatch, broker_watch
from fleetbus.api.console.broker_rates import RATES, Rates
from fleetbus.api.console.charts import TimeChart, time_chart
from fleetbus.api.console.feed import Feed
from fleetbus.api.console.latest import Latest, latest_for
from fleetbus.api.console.live import Shared, live_stream, newest_of
from fleetbus.api.console.my_work import my_work, my_work_panel
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import ADMINS, DASHBOARD
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.hazards import HazardState
from fleetbus.api.services.stored_events import EventRecord
from fleetbus.api.services.team import TeamView
from fleetbus.broker.management import ManagementError
from fleetbus.schemas.roles import WATCHERS, UserRole
from fleetbus.schemas.routing import EventType
from fleetbus.workers.team import TeamMember
from fleetbus.workers.telemetry import battery_low as is_battery_low

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(DASHBOARD))]
Watcher = Annotated[User, Depends(Allowed(WATCHERS, "the live team on the dashboard"))]
Repairer = Annotated[User, Depends(Allowed(ADMINS, "repair the account registry's drift"))]
#: Hazard ids listed per state; the rest are counted.
IDS_SHOWN = 12
OPEN = [state for state in HazardState if state is not HazardState.CLEARED]
#: Events that change the hazards at once: shown without waiting for the next refresh. A
#: localisation does so only from a robot the team did not have localised (it may open the hazard
#: gate); the others come often, from every robot, and show at the next refresh, as statuses do.
NEWS = frozenset({EventType.HAZARD.value})


async def team_view(service: Service, latest: Latest) -> TeamView:
    """The team with the last-seen times kept in memory; a robot shown for the first time is read
    from the store first (once)."""
    view = await service.team.view(latest.last_seen())
    if await latest.seed([member.robot.name for member in view.members]):
        view = await service.team.view(latest.last_seen())
    return view


def attention_first(members: list[TeamMember], latest: Latest, battery_low: float) -> list[TeamMember]:
    """The team in the order an operator looks at it: stale, then not localised, then out of
    service, then battery low, then the rest; by name within each."""

    def rank(member: TeamMember) -> tuple[bool, bool, bool, bool, str]:
        battery = latest.of(member.robot.name).battery
        return (
            not member.stale,
            member.robot.localised,
            member.robot.in_service,
            battery is None or not is_battery_low(battery, battery_low),
            member.robot.name,
        )

    return sorted(members, key=rank)


class RegistryCheck:
    """The registry panel's drift, checked again at most every ``every_s`` (the check lists every
    account of the broker: a quarter of a second with 1,000 robots)."""

    def __init__(self, every_s: float) -> None:
        self._every_s = every_s
        self._checked: tuple[float, dict[str, object]] | None = None
        self._lock = asyncio.Lock()

    async def current(self, svc: Service, fresh: bool = False) -> dict[str, object]:
        async with self._lock:
            if fresh or self._checked is None or time.monotonic() - self._checked[0] > self._every_s:
                found = await _registry(svc)
                self._checked = (time.monotonic(), {**found, "checked_at": datetime.now(timezone.utc)})
            return self._checked[1]


def rate_charts(rates: Rates | None) -> list[tuple[str, TimeChart]]:
    """The broker panel's charts: each message rate over the last hour (none before the broker
    has two samples of it)."""
    if rates is None:
        return []
    return [
        (f"rate-{counter}", time_chart(f"messages {what}", "msg/s", rates.spans[counter], height=160))
        for counter, what in RATES.items()
        if rates.spans.get(counter)
    ]


class DashboardView:
    """What every open dashboard shows live; one per API process, shared by all of them."""

    def __init__(self, service: Service, feed: Feed, latest: Latest, broker: BrokerWatch) -> None:
        self._service = service
        self._feed = feed
        self._latest = latest
        self._broker = broker
        self.snapshot = Shared(self._render)
        self.registry = RegistryCheck(service.settings.console_registry_check_s)
        self.recent_limit = service.settings.console_recent_events
        self._localised: frozenset[str] = frozenset()
        """The robots the team had localised at the last render."""

    async def _render(self) -> list[str]:
        service = self._service
        team = await team_view(self._service, self._latest)
        self._localised = frozenset(m.robot.name for m in team.members if m.robot.localised)
        settings = self._service.settings
        shown = attention_first(team.members, self._latest, settings.battery_low_percent)[
            : settings.console_team_rows
        ]
        hazards = await service.hazards.newest_by_state(OPEN, IDS_SHOWN)
        counts = await service.hazards.counts()
        gaps: Counter[str] = Counter()
        missing: Counter[str] = Counter()
        for gap in await service.ledger.gaps():
            gaps[gap.robot_id] += 1
            missing[gap.robot_id] += gap.size
        mounts = {mount.robot: mount for mount in await service.channels.mounts()}
        health, dead_letters = self._broker.current()
        return [
            fragment(
                "dashboard/team.html",
                team=team,
                shown=shown,
                latest=self._latest,
                health=health,
                gaps=gaps,
                missing=missing,
                mounts=mounts,
                battery_is_low=lambda percent: is_battery_low(percent, settings.battery_low_percent),
            ),
            fragment(
                "dashboard/hazards.html",
                states=OPEN,
                hazards=hazards,
                counts=counts,
                ids_shown=IDS_SHOWN,
            ),
            fragment("dashboard/dead_letters.html", count=dead_letters),
            # central's sites (none elsewhere): link up while the site's account is connected
            fragment(
                "dashboard/sites.html",
                sites=await service.sites.summaries(),
                reports=await service.sites.reports(),
                health=health,
                alert_at=self._service.settings.uplink_alert_at,
            ),
            fragment("dashboard/broker.html", health=health, charts=rate_charts(health.rates)),
            fragment("dashboard/feed.html", feed=self._feed),
        ]

    async def events(self, records: list[EventRecord]) -> list[str]:
        self.snapshot.want(newest_of(records, NEWS))
        localised = self._localised
        self.snapshot.want(
            newest_of([r for r in records if r.robot_id not in localised], {EventType.LOCALISATION.value})
        )
        return [fragment("dashboard/event.html", event=record) for record in records[-self.recent_limit :]]

    async def personal(self, request: Request) -> list[str]:
        return await my_work_panel(request)

    async def newest(self) -> list[str]:
        """The newest events, for the page as first rendered (the stream adds the later ones)."""
        found = await self._service.events.newest(self.recent_limit)
        return [fragment("dashboard/event.html", event=record) for record in found]


def dashboard_view(request: Request) -> DashboardView:
    state = request.app.state
    if getattr(state, "dashboard", None) is None:
        state.dashboard = DashboardView(state.service, state.feed, latest_for(request), broker_watch(request))
    return state.dashboard


View = Annotated[DashboardView, Depends(dashboard_view)]


async def _registry(svc: Service) -> dict[str, object]:
    """The registry panel's drift (an admin's only: it names every account)."""
    try:
        return {"drift": await svc.account_check.drift(), "problem": None}
    except ServiceRefusal as refusal:
        return {"drift": [], "problem": refusal.detail}
    except (ManagementError, httpx.TransportError) as error:
        return {"drift": [], "problem": f"the broker's management API failed: {error}"}


@router.get("/console/", response_class=HTMLResponse)
async def dashboard(
    request: Request, user: Viewer, view: View, svc: ServiceDep, repaired: int | None = None
) -> Response:
    mine = await my_work(svc, user)
    if user.role not in WATCHERS:
        cursor = request.app.state.feed.cursor
        return render(request, "dashboard/mine.html", user, DASHBOARD, cursor=cursor, **mine)
    return render(
        request,
        "dashboard/page.html",
        user,
        DASHBOARD,
        cursor=request.app.state.feed.cursor,
        fragments=await view.snapshot(),
        events=await view.newest(),
        recent_limit=view.recent_limit,
        registry=await view.registry.current(svc, fresh=repaired is not None)
        if user.role is UserRole.ADMIN
        else None,
        repaired=repaired,
        **mine,
    )


@router.post("/console/registry/repair", response_class=HTMLResponse)
async def repair_registry(admin: Repairer, svc: ServiceDep) -> Response:
    """Repair the registry's drift (as `POST /registry/repair`), then back to the dashboard."""
    repaired = await svc.account_check.repair(admin.name)
    return RedirectResponse(f"/console/?repaired={len(repaired)}#registry", status_code=303)


@router.get("/console/stream/dashboard")
async def dashboard_stream(request: Request, user: Watcher, view: View) -> Response:
    return live_stream(view, request.app.state.feed, request)


class MyWorkView:
    """The dashboard of a user who does not watch the team: their own work alone, live."""

    async def snapshot(self) -> list[str]:
        return []

    async def events(self, records: list[EventRecord]) -> list[str]:
        return []  # missions and mounts change through the services: each tick shows them

    async def personal(self, request: Request) -> list[str]:
        return await my_work_panel(request)


@router.get("/console/stream/my-work")
async def my_work_stream(request: Request, user: Viewer) -> Response:
    return live_stream(MyWorkView(), request.app.state.feed, request)
