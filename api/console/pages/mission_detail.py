"""A mission's page, live: its sensor data on a map, and its discussion.

The sensor data are the ``measurement`` events recorded under the mission (a robot's readings
while its operator is checked in). The page loads the newest ``FLEETBUS_CONSOLE_MISSION_POINTS``
of them from :func:`points` as one JSON document, and ``static/mission_map.js`` clusters them in
the browser with Leaflet.markercluster, each point and cluster coloured by value. New readings
reach the page through the console's live stream (one fragment each, added to a list the map
script draws from), and so does the discussion, re-read at most every half second.

Comments are added through :class:`~fleetbus.api.services.mission_comments.MissionComments`, the rule the
HTTP API and the command line use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import JSONResponse, RedirectResponse, Response

from fleetbus.api.console.live import Shared, live_stream
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import MISSIONS
from fleetbus.api.console.templating import fragment
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.stored_events import EventRecord, to_micros
from fleetbus.schemas.roles import MISSION_DATA_READERS
from fleetbus.schemas.routing import EventType

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(MISSIONS))]
MEASUREMENT = EventType.MEASUREMENT.value
#: How often at most one open page reads its mission's discussion again.
THREAD_EVERY_S = 0.5


def _service(request: Request) -> Service:
    return request.app.state.service


def point_id(record: EventRecord) -> str:
    """A reading's id on the page (the element's, and the map's key): its event's key."""
    return f"p-{record.robot_id}-{record.epoch}-{record.seq}"


def point_of(record: EventRecord) -> dict[str, Any]:
    body = record.body
    return {
        "id": point_id(record),
        "x": body["pose"]["x"],
        "y": body["pose"]["y"],
        "value": body["value"],
        "quantity": body["quantity"],
        "unit": body.get("unit") or "",
        "robot": record.robot_id,
        "at": to_micros(measured_at(record)) // 1000,
    }


def measured_at(record: EventRecord) -> datetime:
    """When the reading was taken: its ``measured_at``, else when it was sent."""
    stamp = record.body.get("measured_at")
    return datetime.fromisoformat(stamp) if stamp else record.sent_at


async def thread_fragment(service: Service, user: User, mission_id: str) -> str:
    """The mission's discussion as ``user`` may read it (:meth:`MissionComments.thread`)."""
    comments = await service.mission_comments.thread(user, mission_id)
    return fragment("missions/thread.html", comments=comments)


@dataclass
class MissionPage:
    """One open mission page's live view: its discussion (state), its new readings (events)."""

    service: Service
    user: User
    mission_id: str
    _thread: Shared = field(init=False)

    def __post_init__(self) -> None:
        self._thread = Shared(self._render_thread, THREAD_EVERY_S)

    async def _render_thread(self) -> list[str]:
        return [await thread_fragment(self.service, self.user, self.mission_id)]

    async def snapshot(self) -> list[str]:
        return await self._thread()

    async def events(self, records: list[EventRecord]) -> list[str]:
        if self.user.role not in MISSION_DATA_READERS:
            return []
        return [
            fragment("missions/point.html", point=point_of(record))
            for record in records
            if record.type == MEASUREMENT and record.mission_id == self.mission_id
        ]


@router.get("/console/stream/missions/{mission_id}")
async def mission_stream(request: Request, user: Viewer, mission_id: str) -> Response:
    svc = _service(request)
    await svc.missions.get(user, mission_id)  # a client streams its own missions only
    return live_stream(MissionPage(svc, user, mission_id), request.app.state.feed, request)


def points_document(records: list[EventRecord], limit: int) -> dict[str, Any]:
    """The newest ``limit`` of ``records`` (newest first), oldest first, compactly: each point a
    row ``[x, y, value, quantity, robot, epoch, seq, at]``, the texts once in their own lists
    (a third of the bytes of an object a point)."""
    robots: dict[str, int] = {}
    epochs: dict[str, int] = {}
    quantities: dict[str, int] = {}
    units: list[str] = []
    rows = []
    for record in reversed(records[:limit]):
        body = record.body
        quantity = quantities.setdefault(body["quantity"], len(quantities))
        if quantity == len(units):
            units.append(body.get("unit") or "")
        rows.append(
            [
                body["pose"]["x"],
                body["pose"]["y"],
                body["value"],
                quantity,
                robots.setdefault(record.robot_id, len(robots)),
                epochs.setdefault(record.epoch, len(epochs)),
                record.seq,
                to_micros(measured_at(record)) // 1000,
            ]
        )
    return {
        "limit": limit,
        "more": len(records) > limit,
        "quantities": [[name, unit] for name, unit in zip(quantities, units, strict=True)],
        "robots": list(robots),
        "epochs": list(epochs),
        "points": rows,
    }


@router.get("/console/missions/{mission_id}/points")
async def points(request: Request, user: Viewer, mission_id: str) -> Response:
    """The newest readings recorded under the mission (at most the setting), as JSON."""
    svc = _service(request)
    limit = svc.settings.console_mission_points
    found = await svc.mission_events.recorded(user, mission_id, MEASUREMENT, limit + 1, newest_first=True)
    return JSONResponse(points_document(found, limit), headers={"Cache-Control": "no-store"})


@router.post("/console/missions/{mission_id}/comments")
async def add_comment(
    request: Request,
    user: Viewer,
    mission_id: str,
    text: Annotated[str, Form()] = "",
) -> Response:
    """Comment (the service's rule: who may, how long); back to the mission's discussion."""
    from fleetbus.api.console.pages.missions import show_detail

    try:
        await _service(request).mission_comments.add(user, mission_id, text)
    except ServiceRefusal as refused:
        return await show_detail(request, user, mission_id, refused.detail, refused.status, comment=text)
    return RedirectResponse(
        f"/console/missions/{mission_id}?done=commented#mission-discussion", status_code=303
    )
