"""Messages: search the recording (robot, type, time range, field conditions), a message's trace,
a robot's timeline, and the live tail of what the user's stream receives.

The search, the trace and the timeline call :mod:`fleetbus.workers.recorder.queries`, as
``fleetbus query``, ``fleetbus trace`` and ``fleetbus timeline`` and the API's ``/recording``
routes do; the live tail is the console's feed filtered by :mod:`fleetbus.api.console.following`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Annotated

import httpx
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import HTMLResponse, Response
from pydantic import BaseModel

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.following import MountBook, TailView
from fleetbus.api.console.forms import FormProblem, limit_of, moment, robot_name
from fleetbus.api.console.live import live_stream
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import MESSAGES
from fleetbus.api.console.templating import fragment, render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.api.services.recording import RecordedMessage, Timeline, Trace
from fleetbus.broker.management import ManagementError
from fleetbus.broker.routes import RouteMap
from fleetbus.schemas.routing import NOTIFY_EXCHANGE, inbox_queue
from fleetbus.workers.recorder.queries import SEARCH_LIMIT
from fleetbus.workers.recorder.summary import summarize

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(MESSAGES))]
DEFAULT_LIMIT = SEARCH_LIMIT
SUMMARY_WIDTH = 120
#: A timeline's window when the form gives no start (as ``fleetbus timeline`` and the API).
TIMELINE_WINDOW = timedelta(hours=1)


class SearchForm(BaseModel):
    """The search as typed; every field a string, as the browser sent it (empty when left blank)."""

    type: str = ""
    robot: str = ""
    since: str = ""
    until: str = ""
    where: str = ""
    limit: str = ""

    @property
    def conditions(self) -> list[str]:
        return [line.strip() for line in self.where.splitlines() if line.strip()]


class TimelineForm(BaseModel):
    robot: str = ""
    since: str = ""
    until: str = ""
    limit: str = ""


@dataclass
class SearchResult:
    records: list[RecordedMessage] = field(default_factory=list)
    limit: int = DEFAULT_LIMIT
    problem: str | None = None

    @property
    def newest_only(self) -> bool:
        """More may match than the table shows (it shows the newest ``limit``)."""
        return len(self.records) >= self.limit


async def search(svc: Service, form: SearchForm) -> SearchResult:
    """The recorded messages of the form's type meeting every condition, oldest first (the newest
    ``limit`` of them), as ``fleetbus query`` and ``GET /recording/records/{type}`` answer."""
    most = svc.settings.console_search_limit
    try:
        limit = limit_of(form.limit, DEFAULT_LIMIT, most)
        conditions = svc.recording_queries.conditions(form.conditions, form.type)
        found = await svc.recording_queries.find(
            form.type,
            conditions,
            robot_id=robot_name(form.robot),
            since=moment("since", form.since),
            until=moment("until", form.until),
            limit=limit,
            newest_first=True,
        )
    except (ServiceRefusal, FormProblem) as error:
        return SearchResult(problem=str(error))
    return SearchResult(list(reversed(found)), limit)


async def route_map(svc: Service) -> tuple[RouteMap | None, str | None]:
    """The broker's routes now, or why they are unknown (the management API did not answer)."""
    try:
        return await svc.route_map(), None
    except (ManagementError, httpx.HTTPError) as error:
        return None, f"the broker's management API did not answer ({error}); queues and consumers unknown"


def mount_book(request: Request) -> MountBook:
    state = request.app.state
    if getattr(state, "mount_book", None) is None:
        state.mount_book = MountBook(state.service.channels)
    return state.mount_book


Book = Annotated[MountBook, Depends(mount_book)]


def tail_view(user: User, svc: Service, book: MountBook) -> TailView:
    return TailView(user, book, svc.settings.console_tail_rows)


def is_search_swap(request: Request) -> bool:
    """An htmx request for the search part alone (not a whole page restored from history)."""
    return bool(request.headers.get("hx-request")) and not request.headers.get("hx-history-restore-request")


@router.get("/console/messages", response_class=HTMLResponse)
async def messages(
    request: Request, user: Viewer, svc: ServiceDep, book: Book, form: Annotated[SearchForm, Query()]
) -> Response:
    result = await search(svc, form) if form.type.strip() else None
    context = {
        "form": form,
        "result": result,
        "types": await svc.recording_queries.types(),
        "most": svc.settings.console_search_limit,
        "summarize": summarize,
        "width": SUMMARY_WIDTH,
    }
    if is_search_swap(request):
        # 200 even for a problem: htmx swaps in only what a successful answer brings
        return HTMLResponse(fragment("messages/search.html", **context))
    view = tail_view(user, svc, book)
    return render(
        request,
        "messages/page.html",
        user,
        MESSAGES,
        status_code=422 if result is not None and result.problem else 200,
        cursor=request.app.state.feed.cursor,
        following=await view.snapshot(),
        tail=await view.recent(svc.events),
        tail_rows=svc.settings.console_tail_rows,
        **context,
    )


@router.get("/console/stream/messages")
async def messages_stream(request: Request, user: Viewer, svc: ServiceDep, book: Book) -> Response:
    return live_stream(tail_view(user, svc, book), request.app.state.feed, request)


@router.get("/console/messages/trace", response_class=HTMLResponse)
async def message_trace(request: Request, user: Viewer, svc: ServiceDep, message_id: str = "") -> Response:
    """Where a message came from, what the service made of it, the queues that receive it and their
    consumers now, and the notifications it caused (as ``fleetbus trace``)."""
    message_id = message_id.strip()
    result: Trace | None = None
    routes_unknown = None
    if message_id:
        routes, routes_unknown = await route_map(svc)
        result = await svc.recording_queries.trace(message_id, routes)
    found = result is not None and result.origin is not None
    return render(
        request,
        "messages/trace.html",
        user,
        MESSAGES,
        status_code=404 if message_id and not found else 200,
        message_id=message_id,
        result=result if found else None,
        routes_unknown=routes_unknown,
        clock=lambda moment: f"{moment.astimezone(timezone.utc):%Y-%m-%d %H:%M:%S} UTC",
        summarize=summarize,
        width=SUMMARY_WIDTH,
    )


@router.get("/console/messages/timeline", response_class=HTMLResponse)
async def robot_timeline(
    request: Request, user: Viewer, svc: ServiceDep, form: Annotated[TimelineForm, Query()]
) -> Response:
    """Fault analysis: what the robot sent and was sent in the window, every type in time order
    (as ``fleetbus timeline``)."""
    result: Timeline | None = None
    problem = routes_unknown = None
    inbound: list[str] = []
    start = None
    try:
        name = robot_name(form.robot)
        start = moment("since", form.since) or datetime.now(timezone.utc) - TIMELINE_WINDOW
        end = moment("until", form.until)
        most = limit_of(form.limit, DEFAULT_LIMIT, svc.settings.console_search_limit)
    except FormProblem as error:
        problem, name = str(error), None
    if name is not None:
        routes, routes_unknown = await route_map(svc)
        inbound = routes.keys_into(inbox_queue(name), NOTIFY_EXCHANGE) if routes else []
        result = await svc.recording_queries.timeline(name, start, end, inbound=inbound, limit=most)
    return render(
        request,
        "messages/timeline.html",
        user,
        MESSAGES,
        status_code=422 if problem else 200,
        form=form,
        start=start,
        problem=problem,
        result=result,
        inbound=inbound,
        routes_unknown=routes_unknown,
        summarize=summarize,
        width=SUMMARY_WIDTH,
    )
