"""Alerts: a banner on every live page with the alerts to acknowledge, and the Alerts page with
them all and the last acknowledged (who, when); live.

Every page loads the banner as it opens (``GET /console/alerts/banner``), and a live page's own
stream keeps it current (:func:`banner_fragments`, which :mod:`..live` adds to every stream's
state), without a stream of its own. The roles that acknowledge
(:data:`~fleetbus.api.services.alerts.ACKNOWLEDGERS`, the rule the API and the command line ask too) see an
Acknowledge button; it posts with htmx, which sends the
CSRF header every console request carries, and the answer says who acknowledged it and when.
"""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse, Response

from fleetbus.api.console.live import Shared, live_stream
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import ALERTS
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.parameters import AlertId
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.alerts import ACKNOWLEDGERS, MEANING, AlertList, acknowledged_text
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.stored_events import EventRecord

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(ALERTS))]
Acknowledger = Annotated[User, Depends(Allowed(ACKNOWLEDGERS, "acknowledge alerts"))]
#: Alerts the banner lists; the rest are counted, and all are on the Alerts page.
BANNER_SHOWN = 5
MEANINGS = {kind.value: text for kind, text in MEANING.items()}


def acts(user: User) -> bool:
    return user.role in ACKNOWLEDGERS


def banner_html(listing: AlertList, may_act: bool) -> str:
    return fragment("alerts/banner.html", alerts=listing.unacknowledged, acts=may_act, shown=BANNER_SHOWN)


def panel_html(listing: AlertList, may_act: bool, oob: bool = False) -> str:
    return fragment("alerts/panel.html", listing=listing, acts=may_act, meaning=MEANINGS, oob=oob)


class AlertsView:
    """The banner and the Alerts page's panel, for viewers who acknowledge (``acts``) or only
    watch; one of each per API process, shared by every open page (one store read per refresh)."""

    def __init__(self, service: Service, acts: bool) -> None:
        self._service = service
        self._acts = acts
        self.banner = Shared(self._banner)
        self.snapshot = Shared(self._render)

    async def _banner(self) -> list[str]:
        return [banner_html(await self._service.alerts.listing(), self._acts)]

    async def _render(self) -> list[str]:
        return [panel_html(await self._service.alerts.listing(acknowledged=True), self._acts)]

    async def events(self, records: list[EventRecord]) -> list[str]:
        return []  # alerts are raised by the check, from the store: the snapshot shows them


def _views(request: Request) -> dict[bool, AlertsView]:
    state = request.app.state
    if getattr(state, "alerts_views", None) is None:
        state.alerts_views = {flag: AlertsView(state.service, flag) for flag in (True, False)}
    return state.alerts_views


async def banner_fragments(request: Request) -> list[str]:
    """The banner for the stream of a page ``request`` opened: for the roles that watch the team
    (the Alerts page's), none for the others."""
    user: User | None = getattr(request.state, "user", None)
    if user is None or not ALERTS.admits(user.role):
        return []
    return await _views(request)[acts(user)].banner()


def alerts_view(request: Request, user: Viewer) -> AlertsView:
    return _views(request)[acts(user)]


View = Annotated[AlertsView, Depends(alerts_view)]


@router.get("/console/alerts", response_class=HTMLResponse)
async def alerts_page(request: Request, user: Viewer) -> Response:
    service: Service = request.app.state.service
    listing = await service.alerts.listing(acknowledged=True)
    return render(
        request,
        "alerts/page.html",
        user,
        ALERTS,
        cursor=request.app.state.feed.cursor,
        panel=panel_html(listing, acts(user)),
        every=service.settings.alerts_check_s,
        hazards_every=service.settings.alerts_hazard_check_s,
    )


@router.get("/console/alerts/banner", response_class=HTMLResponse)
async def alerts_banner(user: Viewer, view: View) -> Response:
    """The banner alone, for a page as it loads (a live page's stream then keeps it current)."""
    return HTMLResponse("\n".join(await view.banner()))


@router.get("/console/stream/alerts")
async def alerts_stream(request: Request, user: Viewer, view: View) -> Response:
    return live_stream(view, request.app.state.feed, request)


@router.post("/console/alerts/{alert_id}/acknowledge", response_class=HTMLResponse)
async def acknowledge_alert(request: Request, user: Acknowledger, alert_id: AlertId) -> Response:
    """Acknowledge an alert (as ``POST /alerts/{alert_id}/acknowledge``); the answer says who and
    when, and brings the banner (and, on the Alerts page, its panel) up to date."""
    service: Service = request.app.state.service
    try:
        alert = await service.alerts.acknowledge(alert_id, user.name, user.role)
    except ServiceRefusal as refused:
        return HTMLResponse(fragment("alerts/notice.html", text=refused.detail, problem=True))
    text = acknowledged_text(alert)
    _refresh(request)
    listing = await service.alerts.listing(acknowledged=True)
    parts = [fragment("alerts/notice.html", text=text, problem=False), _oob(banner_html(listing, True))]
    if request.headers.get("hx-current-url", "").split("?")[0].endswith(ALERTS.path):
        parts.append(panel_html(listing, True, oob=True))
    return HTMLResponse("\n".join(parts))


def _refresh(request: Request) -> None:
    """Every open page's banner and panel rendered anew at its next refresh (not half a second later)."""
    mark = time.time_ns() // 1000
    for view in _views(request).values():
        view.banner.want(mark)
        view.snapshot.want(mark)


def _oob(html: str) -> str:
    """The banner swapped in by its id, whatever the button's target."""
    return html.replace('id="alerts-banner"', 'id="alerts-banner" hx-swap-oob="true"', 1)
