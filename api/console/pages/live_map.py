"""The live map: a stored version of the team's map, and over it, in the map's world coordinates,
each robot's last pose, the hazards by state with their ids, the beacons and where people are
likely stranded; live.

The markers are drawn in metres (:class:`~..map_image.Frame`), not in a version's pixels, so one
rendering of them serves every open map whatever version it shows: N open maps cost one
refresh of a few store reads (the robots, the hazard counts and the newest hazards of each
state, the beacons, the newest version), bounded however many hazards there are, and at most
every two seconds two more (the beacons again and the last ten minutes' sightings: where people
are likely stranded). Choosing another version swaps the image and its frame (htmx); the
markers stay.
"""

from __future__ import annotations

import asyncio
import time
from datetime import datetime, timedelta, timezone
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse, Response

from fleetbus.api.console.latest import Latest, latest_for
from fleetbus.api.console.live import Shared, live_stream, newest_of
from fleetbus.api.console.map_image import ImageUnreadable, MapImages
from fleetbus.api.console.pages.dashboard import OPEN
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import MAP
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.console.trails import WINDOWS, hazard_times, position, trails, where_seen
from fleetbus.api.parameters import MapVersionNumber
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import NotFound
from fleetbus.api.services.hazards import LARGEST_INTEGER, Hazard, HazardState
from fleetbus.api.services.maps import MapVersion
from fleetbus.api.services.stored_events import EventRecord
from fleetbus.schemas.routing import EventType
from fleetbus.workers.beacons import DEFAULT_WINDOW

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(MAP))]
Version = Annotated[
    int | None, Query(ge=1, le=LARGEST_INTEGER, description="a stored map version; the newest by default")
]
#: Events that change the map at once: shown without waiting for the next refresh. (Poses come
#: with statuses, often; they are in memory and show at the next refresh.)
NEWS = frozenset({EventType.HAZARD.value, EventType.MAP.value})
#: The recent sightings are read again at most this often: each read is every sighting of the
#: last ten minutes (:func:`~fleetbus.workers.beacons.stranded`), many when guides report often.
SIGHTINGS_EVERY_S = 2.0
#: At most this many provisional marks of new hazards kept on a page (each is drawn until its
#: hazard is registered).
NEWS_MAX = 50
#: A hazard event not registered this long after the map saw it stored is no longer awaited (a
#: site's hazard, say, is registered at central by its uplink, not by this event).
REGISTERING_S = 5.0
#: The live fragments of the map, in the order :meth:`MapView.snapshot` gives them.
PARTS = ("marks", "hazards", "robots", "beacons", "newest")


def event_mark(robot_id: str, epoch: str, seq: int) -> str:
    """A hazard's event as its marks name it (``data-event``): the provisional mark sent from the
    event and the registered hazard's mark share it, so the map knows when to drop the first."""
    return f"{robot_id}-{epoch}-{seq}"


class MapView:
    """What every open map shows live; one per API process, shared by all of them."""

    def __init__(self, service: Service, latest: Latest) -> None:
        self._service = service
        self._latest = latest
        self.images = MapImages(
            service.maps, service.settings.console_map_pixels, service.settings.console_map_cache
        )
        self.snapshot = Shared(self._render)
        self._unregistered: dict[tuple[str, str, int], float] = {}
        """Hazard events stored and not yet seen registered (by their key; when first seen)."""
        self._heard: list[dict[str, Any]] = []
        self._heard_at = -float("inf")

    async def _stranded(self) -> list[dict[str, Any]]:
        """Where people are likely stranded, read at most every :data:`SIGHTINGS_EVERY_S`."""
        now = asyncio.get_running_loop().time()
        if now - self._heard_at >= SIGHTINGS_EVERY_S:
            since = datetime.now(timezone.utc) - DEFAULT_WINDOW
            self._heard = await self._service.beacons.stranded(since)
            self._heard_at = now
        return self._heard

    async def _render(self) -> list[str]:
        service = self._service
        robots = await service.team.robots()
        await self._latest.seed([robot.name for robot in robots])
        settings = self._service.settings
        grouped = await self._service.hazards.newest_by_state(OPEN, settings.console_map_hazards)
        cleared = await service.hazards.cleared(settings.console_map_cleared)
        grouped[HazardState.CLEARED] = cleared
        self._look_for_registered(grouped)
        counts = await service.hazards.counts()
        beacons = await service.beacons.registry()
        heard = await self._stranded()
        newest = await service.maps.newest()
        context = {
            "robots": robots,
            "latest": self._latest,
            "states": list(HazardState),
            "hazards": grouped,
            "counts": counts,
            "position": position,
            "event_mark": event_mark,
            "beacons": beacons,
            "stranded": heard,
            "stranded_ids": {entry["beacon_id"] for entry in heard},
            "window_minutes": int(DEFAULT_WINDOW.total_seconds() // 60),
        }
        return [fragment(f"map/{part}.html", newest=newest, **context) for part in PARTS]

    def _look_for_registered(self, shown: dict[HazardState, list[Hazard]]) -> None:
        """A hazard's event is stored before the worker registers the hazard (gives it its id), so
        a render the event asked for may come too early to draw it: until it is drawn (or
        :data:`REGISTERING_S` passed), each render asks for the next."""
        if not self._unregistered:
            return
        for hazard in (hazard for hazards in shown.values() for hazard in hazards):
            self._unregistered.pop((hazard.robot_id, hazard.epoch, hazard.seq), None)
        now = time.monotonic()
        for key, seen in list(self._unregistered.items()):
            if now - seen > REGISTERING_S:
                del self._unregistered[key]
        if self._unregistered:
            self.snapshot.want(time.time_ns() // 1000)

    async def events(self, records: list[EventRecord]) -> list[str]:
        """A new hazard's provisional mark, at once, where its event says (the map draws it until
        the render of the state has the hazard registered, with its id); the rest of what the map
        shows is state, refreshed by the snapshot."""
        now = time.monotonic()
        news = []
        for record in records:
            if record.type == EventType.HAZARD.value:
                self._unregistered.setdefault(record.key, now)
                if (pose := where_seen(record.body)) is not None:
                    key = event_mark(*record.key)
                    at = {"x": float(pose["x"]), "y": float(pose["y"])}
                    news.append(fragment("map/news.html", record=record, key=key, at=at))
        self.snapshot.want(newest_of(records, NEWS))
        return news

    async def stored(self, version: int | None) -> MapVersion | str:
        """The stored version (the newest for None), or why there is none."""
        try:
            return await self._service.maps.version(version)
        except NotFound as missing:
            return missing.detail

    async def visible(self, user: User, version: int) -> MapVersion:
        """The stored version if ``user`` may see it (:func:`~fleetbus.api.services.maps.map_version_for`)."""
        return await self._service.maps.visible(user, version)


def map_view(request: Request) -> MapView:
    state = request.app.state
    if getattr(state, "live_map", None) is None:
        state.live_map = MapView(state.service, latest_for(request))
    return state.live_map


View = Annotated[MapView, Depends(map_view)]


async def _frame_context(view: MapView, version: int | None) -> dict[str, Any]:
    """The chosen version's frame (or why there is none) and the markers drawn over it."""
    found = await view.stored(version)
    frame = await view.images.frame(found) if isinstance(found, MapVersion) else None
    parts = dict(zip(PARTS, await view.snapshot(), strict=True))
    return {"frame": frame, "why": found if isinstance(found, str) else None, "marks": parts["marks"]}


@router.get("/console/map", response_class=HTMLResponse)
async def live_map(request: Request, user: Viewer, view: View, version: Version = None) -> Response:
    versions = await request.app.state.service.maps.versions()
    parts = dict(zip(PARTS, await view.snapshot(), strict=True))
    return render(
        request,
        "map/page.html",
        user,
        MAP,
        cursor=request.app.state.feed.cursor,
        versions=versions,
        windows=WINDOWS,
        lists=[parts["hazards"], parts["robots"], parts["beacons"]],
        news_max=NEWS_MAX,
        newest=parts["newest"],
        **await _frame_context(view, version),
    )


@router.get("/console/map/frame", response_class=HTMLResponse)
async def map_frame(user: Viewer, view: View, version: Version = None) -> Response:
    """The chosen version's image and frame, for the version select (htmx)."""
    body = fragment("map/frame.html", **await _frame_context(view, version))
    where = "/console/map" if version is None else f"/console/map?version={version}"
    return HTMLResponse(body, headers={"HX-Push-Url": where})


@router.get("/console/map/trails")
async def map_trails(
    request: Request,
    user: Viewer,
    minutes: Annotated[int, Query(ge=1, le=max(WINDOWS))] = 60,
    until: Annotated[datetime | None, Query(description="the window's end (UTC); now by default")] = None,
) -> Response:
    """Each robot's trail over the last ``minutes`` before ``until``, from its stored poses
    (sampled when the window holds more than ``FLEETBUS_CONSOLE_TRAIL_POINTS``), and the hazards of
    the window with the times of their steps (the newest ``FLEETBUS_CONSOLE_MAP_HAZARDS``)."""
    end = until or datetime.now(timezone.utc)
    end = end.replace(tzinfo=timezone.utc) if end.tzinfo is None else end.astimezone(timezone.utc)
    service: Service = request.app.state.service
    robots = [robot.name for robot in await service.team.robots()]
    points = service.settings.console_trail_points
    window = timedelta(minutes=minutes)
    found = await trails(service.events, robots, end, window, points)
    during = await service.hazards.during(end - window, end, service.settings.console_map_hazards)
    found["hazards"] = hazard_times(during)
    return JSONResponse(found, headers={"Cache-Control": "no-store"})


async def png_answer(view: MapView, user: User, version: int) -> Response:
    """A stored version's image as a PNG (the live map's, and the new mission form's), if ``user``
    may see that version: 404 when there is none, 403 when it is not for ``user``'s role."""
    found = await view.visible(user, version)
    try:
        png = await view.images.png(found)
    except ImageUnreadable as error:
        raise HTTPException(422, detail=str(error)) from None
    # a version never changes: the browser may keep it
    return Response(
        png, media_type="image/png", headers={"Cache-Control": "private, max-age=86400, immutable"}
    )


@router.get("/console/map/{version}.png")
async def map_png(user: Viewer, view: View, version: MapVersionNumber) -> Response:
    return await png_answer(view, user, version)


@router.get("/console/stream/map")
async def map_stream(request: Request, user: Viewer, view: View) -> Response:
    return live_stream(view, request.app.state.feed, request)
