"""A page's live stream: server-sent events carrying HTML fragments, each with an event id.

A page names the :class:`LiveView` that renders its live parts. On connecting, the page is sent
the view's snapshot and, when it says (``Last-Event-ID``) what it saw last, the events it missed,
read from the store (or, past :data:`MISSED_LIMIT`, told to reload); then each batch of the
:class:`~.feed.Feed`: its events' fragments, then the state's that changed, each in an SSE event
of its own (the rows wait for no render of the state). An SSE event carries a JSON list of
fragments. Each fragment is one element with an ``id``, parsed on its own (a table row mixed with
other elements in one piece of HTML would be dropped by the browser's parser): ``static/live.js``
replaces the element with that id, or, for a fragment with ``data-into``, adds it to that list.
So a fragment sent twice shows once.
A fragment of the state (the snapshot's) that did not change since this page was last sent it is
not sent again; an event's fragments are sent as they come (remembering each would grow with
every event an open page is shown).

An open stream outlives no session: once a second at most it asks whether the session that opened
it is still open, and when it has ended (a logout elsewhere, an administrator) it tells the page
to reload, which then lands on the login form.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import AsyncIterator, Awaitable, Callable, Collection
from contextlib import suppress
from typing import Protocol, runtime_checkable

import anyio
from fastapi import Request
from sse_starlette import EventSourceResponse, ServerSentEvent

from fleetbus.api.console.feed import Batch, Feed, moment_of
from fleetbus.api.services.stored_events import EventRecord, to_micros

FRAGMENT_EVENT = "fragment"
RELOAD_EVENT = "reload"
"""Sent instead of a replay too long to send: the page loads itself again (and shows the newest)."""
MISSED_LIMIT = 10_000
"""At most this many missed events are replayed to a reconnecting page; one that missed more is
told to reload (a replay of the oldest would show them as the newest, and leave a gap after)."""
_ID = re.compile(r'\bid="([^"]+)"')
SESSION_CHECK_S = 1.0
"""How often at most an open stream checks that its session is still open."""
SHUTDOWN_GRACE_S = 2.0
"""How long a stream has to end by itself once the server shuts down (it takes a moment) before
sse-starlette cancels it: less than the server's graceful shutdown timeout."""


class LiveView(Protocol):
    async def snapshot(self) -> list[str]:
        """The fragments of the state the page shows (the team, the hazards...), now."""
        ...

    async def events(self, records: list[EventRecord]) -> list[str]:
        """The fragments ``records`` add to the page (a row each, say); may be none. A batch is
        rendered once for all the view's open pages: they must not depend on who looks."""
        ...


@runtime_checkable
class PersonalView(LiveView, Protocol):
    async def personal(self, request: Request) -> list[str]:
        """Fragments of the state that depend on who looks (the user ``request`` was signed in
        as): sent like the snapshot's, when they changed."""
        ...


def _key(fragment: str) -> str:
    found = _ID.search(fragment)
    return found.group(1) if found else fragment


def last_event_id(request: Request) -> str | None:
    """What the browser saw last: the ``Last-Event-ID`` header its EventSource sends when it
    reconnects by itself, or ``last_event_id`` in the query when ``live.js`` opens a new one."""
    return request.headers.get("last-event-id") or request.query_params.get("last_event_id")


async def _fragments(
    view: LiveView, feed: Feed, request: Request, closing: anyio.Event
) -> AsyncIterator[ServerSentEvent | bytes]:
    # the state's fragments as last sent, by their element's id: a shared render hands every page
    # the same strings, so comparing one with what was sent is mostly an identity check
    sent: dict[str, str] = {}

    def changed(fragments: list[str]) -> list[str]:
        fresh = []
        for fragment in fragments:
            key = _key(fragment)
            if sent.get(key) != fragment:
                sent[key] = fragment
                fresh.append(fragment)
        return fresh

    async with feed.subscribe() as subscription:
        waker = asyncio.create_task(_end_on(closing, subscription.queue))
        try:
            cursor = feed.cursor
            first = changed(await _state(view, request))
            since = moment_of(last_event_id(request))
            if since is not None:
                missed = await feed.missed(since, MISSED_LIMIT)
                if missed is None:
                    too_many = f"more than {MISSED_LIMIT:,} events missed"
                    yield ServerSentEvent(data=too_many, event=RELOAD_EVENT)
                    return
                first += await view.events(missed)
            yield ServerSentEvent(data=json.dumps(first), event=FRAGMENT_EVENT, id=cursor)
            checked = asyncio.get_running_loop().time()
            while True:
                batch: Batch | None = await subscription.queue.get()
                if batch is None:  # dropped for falling behind (the browser reconnects and catches
                    return  # up), or the server shuts down
                if asyncio.get_running_loop().time() - checked >= SESSION_CHECK_S:
                    checked = asyncio.get_running_loop().time()
                    if not await _session_open(request):
                        yield ServerSentEvent(data="the session has ended", event=RELOAD_EVENT)
                        return
                # the batch's rows first, on their own: a page waits for none of the state's
                # render (the team, the hazards: one page renders it, the others wait for it)
                rows = await events_of(view, batch)
                if rows:
                    yield encoded(batch, rows)
                state = changed(await _state(view, request))
                if state:
                    yield encoded(batch, state)
        finally:
            waker.cancel()


async def _end_on(closing: anyio.Event, queue: asyncio.Queue[Batch | None]) -> None:
    """Once the server shuts down, the end-of-stream marker (a dropped page's) wakes the stream."""
    await closing.wait()
    with suppress(asyncio.QueueFull):  # full: the marker is there already
        queue.put_nowait(None)


async def _state(view: LiveView, request: Request) -> list[str]:
    """The view's state, its part for who looks (a :class:`PersonalView`'s), and what every live
    page shows besides (the alerts banner: the app's ``on_every_live_page``, given the request,
    which says who looks)."""
    app = request.scope.get("app")  # none for a view streamed outside the app (its tests)
    every_page = getattr(app.state, "on_every_live_page", None) if app is not None else None
    state = await view.snapshot()
    if isinstance(view, PersonalView):
        state += await view.personal(request)
    return [*state, *(await every_page(request) if every_page else [])]


async def _session_open(request: Request) -> bool:
    """Whether the session the stream was opened with (the console's check put it on the
    request) is still open."""
    session = getattr(request.state, "session", None)
    return session is None or await request.app.state.service.sessions.is_open(session.id)


async def events_of(view: LiveView, batch: Batch) -> list[str]:
    """``view``'s fragments for the batch's events, rendered once for all the view's open pages
    (a view's fragments depend on the events alone, not on who looks)."""
    done = batch.rendered.get(id(view))
    if done is None:
        done = batch.rendered[id(view)] = (view, await view.events(batch.events))
    return done[1]


def encoded(batch: Batch, fragments: list[str]) -> bytes:
    """The server-sent event carrying ``fragments`` after ``batch``, encoded once for every page
    sent the same (the fragments of a shared render are the same strings: the key compares fast)."""
    key = tuple(fragments)
    done = batch.encoded.get(key)
    if done is None:
        event = ServerSentEvent(data=json.dumps(fragments), event=FRAGMENT_EVENT, id=batch.cursor)
        done = batch.encoded[key] = event.encode()
    return done


def live_stream(view: LiveView, feed: Feed, request: Request) -> EventSourceResponse:
    """The answer to a page's ``EventSource``: its fragments until the browser goes away."""
    closing = anyio.Event()  # set by sse-starlette when the server shuts down
    return EventSourceResponse(
        _fragments(view, feed, request, closing),
        ping=15,
        headers={"Cache-Control": "no-store"},
        shutdown_event=closing,
        shutdown_grace_period=SHUTDOWN_GRACE_S,
    )


class Shared:
    """An async render shared by every open page: run at most once per ``interval`` seconds;
    pages asking in between are given the last result. N dashboards cost one read of the store.

    News that changes what the render shows (a hazard's event) need not wait for the interval:
    :meth:`want` asks for a render covering it, which the first page asking then runs, once."""

    def __init__(self, render: Callable[[], Awaitable[list[str]]], interval: float = 0.5) -> None:
        self._render = render
        self._interval = interval
        self._lock = asyncio.Lock()
        self._at = -float("inf")
        self._value: list[str] = []
        self._wanted = 0
        self._covered = 0

    def want(self, news: int) -> None:
        """Render again at the next call, unless a render began after ``news`` (an increasing mark,
        such as the receive time of the newest event that matters) was wanted."""
        self._wanted = max(self._wanted, news)

    async def __call__(self) -> list[str]:
        async with self._lock:
            now = asyncio.get_running_loop().time()
            if now - self._at >= self._interval or self._covered < self._wanted:
                covering = self._wanted
                self._value = await self._render()
                self._at, self._covered = now, covering
            return list(self._value)  # a caller that adds to its copy changes no other page's


def newest_of(records: list[EventRecord], types: Collection[str]) -> int:
    """The receive time (microseconds) of the newest of ``records`` of these types; 0 for none:
    the mark to hand :meth:`Shared.want` when those types change what a render shows."""
    return max((to_micros(record.received_at) for record in records if record.type in types), default=0)
