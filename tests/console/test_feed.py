"""The console's live feed and a page's stream on a real store (SQLite and MongoDB): what they
hand out, and to whom."""

from __future__ import annotations

import asyncio
import json
import logging
from dataclasses import replace
from datetime import datetime, timedelta, timezone

import anyio
import pytest
from sse_starlette import ServerSentEvent
from starlette.requests import Request

from fleetbus.api.console import live
from fleetbus.api.console.feed import Batch, Feed, Subscription, cursor_of, running
from fleetbus.api.console.latest import Latest
from fleetbus.api.console.live import FRAGMENT_EVENT, RELOAD_EVENT, Shared, _fragments
from fleetbus.api.services.stored_events import StoredEvents
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.repositories import Repositories
from tests.store.conftest import store  # noqa: F401  (every repository on each backend)

EPOCH = "20210601T182526564Z-0a1b2c3d"
DEADLINE_S = 15


def received(seq: int, at: datetime, robot: str = "explorer1") -> EventRecord:
    return EventRecord(
        robot_id=robot,
        epoch=EPOCH,
        seq=seq,
        type="status",
        message_id=f"m-{robot}-{seq}",
        sent_at=at,
        received_at=at,
        body={"battery_percent": 80.0},
        user_id=robot,
        exchange=f"{robot}.events",
        routing_key=f"{robot}.status",
    )


Key = tuple[str, str, int]


def sse_data(encoded: bytes) -> str:
    """The data of one encoded server-sent event."""
    lines = encoded.decode().splitlines()
    return "\n".join(line.removeprefix("data: ") for line in lines if line.startswith("data: "))


async def handed_out_until(subscription: Subscription, *last: Key) -> list[Key]:
    """The keys of every event handed to ``subscription`` up to and including all of ``last``
    (sentinels)."""
    keys: list[Key] = []
    async with asyncio.timeout(DEADLINE_S):
        while not set(last) <= set(keys):
            batch = await subscription.queue.get()
            assert isinstance(batch, Batch), "the subscriber was not dropped"
            keys += [record.key for record in batch.events]
    return keys


async def test_an_event_committed_after_a_later_one_is_handed_out_once(store: Repositories) -> None:  # noqa: F811
    # every poll looks back a second; once a tick (here often), the whole overlap
    feed = Feed(StoredEvents(store.events), poll_s=0.01, tick_s=0.05, overlap=timedelta(seconds=5))
    now = datetime.now(timezone.utc)
    async with running(feed), feed.subscribe() as subscription:
        await store.events.write_events([received(1, now)])
        assert await handed_out_until(subscription, ("explorer1", EPOCH, 1)) == [("explorer1", EPOCH, 1)]
        # received 2 s before the event handed out already, but committed only now (another
        # worker's batch): within the overlap, so the next read of the whole overlap finds it
        await store.events.write_events([received(0, now - timedelta(seconds=2))])
        await store.events.write_events([received(2, now + timedelta(milliseconds=1))])
        later = await handed_out_until(subscription, ("explorer1", EPOCH, 0), ("explorer1", EPOCH, 2))
        await store.events.write_events([received(3, now + timedelta(milliseconds=2))])
        later += await handed_out_until(subscription, ("explorer1", EPOCH, 3))
    assert sorted(later) == [("explorer1", EPOCH, seq) for seq in (0, 2, 3)]


async def test_a_read_that_fails_unexpectedly_is_counted_and_the_feed_goes_on(
    store: Repositories,  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every live page waits on the feed: a read failing for any reason (not only a store that
    does not answer) is counted and logged, and the next poll reads again. It used to end the
    feed, every open page then waiting for ever."""
    feed = Feed(StoredEvents(store.events), poll_s=0.01, tick_s=0.05, overlap=timedelta(seconds=5))
    read, failed = feed._read, []

    async def fails_once(back: timedelta) -> list[EventRecord]:
        if not failed:
            failed.append(back)
            raise RuntimeError("a bug in reading")
        return await read(back)

    monkeypatch.setattr(feed, "_read", fails_once)
    async with running(feed), feed.subscribe() as subscription:
        await store.events.write_events([received(1, datetime.now(timezone.utc))])
        assert await handed_out_until(subscription, ("explorer1", EPOCH, 1)) == [("explorer1", EPOCH, 1)]
    assert failed and feed.store_errors == 1


async def test_a_watcher_that_fails_is_counted_and_the_feed_goes_on(
    store: Repositories,  # noqa: F811
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A watcher raising on a batch (the newest values, on a pose without its ``y``) is counted
    and logged; the pages get that batch and the next, and the watcher the next. It used to end
    the feed: every live page frozen, its pings still keeping the browser connected."""
    feed = Feed(StoredEvents(store.events), poll_s=0.01, tick_s=0.05)
    latest = Latest(StoredEvents(store.events))
    feed.watch(latest.observe)
    now = datetime.now(timezone.utc)
    unexpected = replace(received(1, now), body={"pose": {"x": 1.0}})
    with caplog.at_level(logging.ERROR, logger="fleetbus.api.console"):
        async with running(feed), feed.subscribe() as subscription:
            await store.events.write_events([unexpected])
            assert await handed_out_until(subscription, ("explorer1", EPOCH, 1)) == [("explorer1", EPOCH, 1)]
            await store.events.write_events([received(2, now + timedelta(milliseconds=1))])
            assert await handed_out_until(subscription, ("explorer1", EPOCH, 2)) == [("explorer1", EPOCH, 2)]
    assert feed.watcher_errors == 1
    assert [r.exc_info[0] for r in caplog.records if r.exc_info] == [KeyError], caplog.text
    status = latest.of("explorer1").status
    assert status is not None and status.seq == 2, "the watcher is still called"


class Errors(logging.Handler):
    """The errors logged, and an event set at the first."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.logged: list[str] = []
        self.first = asyncio.Event()

    def emit(self, record: logging.LogRecord) -> None:
        self.logged.append(record.getMessage())
        self.first.set()


async def test_a_feed_that_ends_says_so_at_once(
    store: Repositories,  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Not only once the API stops (awaiting the task): live pages wait on it meanwhile."""
    feed = Feed(StoredEvents(store.events))

    async def ends() -> None:
        raise RuntimeError("a bug in the feed")

    monkeypatch.setattr(feed, "run", ends)
    errors = Errors()
    logger = logging.getLogger("fleetbus.api.console")
    logger.addHandler(errors)
    try:
        with pytest.raises(RuntimeError):
            async with running(feed):
                await asyncio.wait_for(errors.first.wait(), DEADLINE_S)
    finally:
        logger.removeHandler(errors)
    [said] = errors.logged
    assert said.startswith("console feed ended (RuntimeError('a bug in the feed'))"), said


async def test_an_event_committed_a_moment_late_is_found_at_the_next_poll(store: Repositories) -> None:  # noqa: F811
    # no look at the whole overlap during the test (the tick is far): the poll's own look back finds it
    feed = Feed(
        StoredEvents(store.events),
        poll_s=0.01,
        tick_s=3600,
        overlap=timedelta(seconds=5),
        recent=timedelta(seconds=1),
    )
    now = datetime.now(timezone.utc)
    async with running(feed), feed.subscribe() as subscription:
        await store.events.write_events([received(1, now)])
        assert await handed_out_until(subscription, ("explorer1", EPOCH, 1)) == [("explorer1", EPOCH, 1)]
        await store.events.write_events([received(0, now - timedelta(milliseconds=500))])
        await store.events.write_events([received(2, now + timedelta(milliseconds=1))])
        later = await handed_out_until(subscription, ("explorer1", EPOCH, 0), ("explorer1", EPOCH, 2))
    assert sorted(later) == [("explorer1", EPOCH, 0), ("explorer1", EPOCH, 2)]


async def test_an_overlap_holding_more_than_a_read_is_read_page_by_page(store: Repositories) -> None:  # noqa: F811
    feed = Feed(StoredEvents(store.events), poll_s=0.01, overlap=timedelta(seconds=5), batch_limit=5)
    now = datetime.now(timezone.utc)
    async with running(feed), feed.subscribe() as subscription:
        twelve = [received(seq, now + timedelta(milliseconds=seq)) for seq in range(12)]
        await store.events.write_events(twelve)
        first = await handed_out_until(subscription, ("explorer1", EPOCH, 11))
        # every event so far is within the overlap, more than one read's worth: the next is found too
        await store.events.write_events([received(12, now + timedelta(milliseconds=12))])
        then = await handed_out_until(subscription, ("explorer1", EPOCH, 12))
    assert first == [("explorer1", EPOCH, seq) for seq in range(12)]
    assert then == [("explorer1", EPOCH, 12)]


async def test_a_subscriber_that_falls_behind_is_dropped_and_counted(store: Repositories) -> None:  # noqa: F811
    feed = Feed(StoredEvents(store.events), poll_s=0.01, tick_s=0.01, queue_size=3)
    async with running(feed), feed.subscribe() as keeping_up, feed.subscribe() as lagging:
        async with asyncio.timeout(DEADLINE_S):
            for _ in range(4):  # a batch (a tick) each: the fourth finds the lagging queue full
                assert await keeping_up.queue.get() is not None
        assert lagging.dropped and feed.dropped == 1 and feed.subscribers == 1
        # the one that keeps up is still handed what comes
        await store.events.write_events([received(0, datetime.now(timezone.utc))])
        assert ("explorer1", EPOCH, 0) in await handed_out_until(keeping_up, ("explorer1", EPOCH, 0))
    left = [lagging.queue.get_nowait() for _ in range(lagging.queue.qsize())]
    assert len(left) == 4 and left[-1] is None, "its 3 batches behind, then the end of its stream"
    assert not keeping_up.dropped


class RowsView:
    """A page with a shared snapshot (one section) and a row per event."""

    def __init__(self) -> None:
        self.snapshot = Shared(self._render, interval=3600)
        self.rendered: list[int] = []
        """The events rendered, in order."""

    async def _render(self) -> list[str]:
        return ['<section id="state">the state</section>']

    async def events(self, records: list[EventRecord]) -> list[str]:
        self.rendered += [record.seq for record in records]
        return [f'<tr id="event-{record.seq}"><td>{record.seq}</td></tr>' for record in records]


def reconnecting(seen: datetime) -> Request:
    """A page's request for its stream, having seen every event up to ``seen``."""
    headers = [(b"last-event-id", cursor_of(seen).encode())]
    return Request({"type": "http", "headers": headers, "query_string": b""})


async def first_event(view: RowsView, feed: Feed, request: Request) -> ServerSentEvent:
    stream = _fragments(view, feed, request, anyio.Event())
    try:
        return await anext(stream)
    finally:
        await stream.aclose()


async def test_a_page_that_missed_more_than_a_replay_is_told_to_reload(
    store: Repositories,  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(live, "MISSED_LIMIT", 3)
    now = datetime.now(timezone.utc)
    await store.events.write_events([received(seq, now + timedelta(milliseconds=seq)) for seq in range(3)])
    feed = Feed(StoredEvents(store.events))
    told = await first_event(RowsView(), feed, reconnecting(now - timedelta(seconds=1)))
    assert told.event == RELOAD_EVENT
    await store.events.write_events([received(3, now + timedelta(milliseconds=3))])
    # one that saw the first two missed two: replayed, with those of the overlap before (the
    # count is of the events after what the page saw, or a busy overlap would reload every page)
    replay = await first_event(RowsView(), feed, reconnecting(now + timedelta(milliseconds=2)))
    assert replay.event == FRAGMENT_EVENT
    assert [row for row in json.loads(replay.data) if row.startswith("<tr")] == [
        f'<tr id="event-{seq}"><td>{seq}</td></tr>' for seq in range(4)
    ]


async def test_a_replay_leaves_the_snapshot_other_pages_are_shown_as_it_was(store: Repositories) -> None:  # noqa: F811
    now = datetime.now(timezone.utc)
    await store.events.write_events([received(0, now)])
    view = RowsView()
    shown = await view.snapshot()  # as a page rendered a moment before its stream opens
    feed = Feed(StoredEvents(store.events))
    first = await first_event(view, feed, reconnecting(now - timedelta(seconds=1)))
    assert first.event == FRAGMENT_EVENT
    assert json.loads(first.data) == [*shown, '<tr id="event-0"><td>0</td></tr>'], "the page's replay"
    # the next page rendered within the interval is given the same snapshot, not the replay's rows
    assert await view.snapshot() == shown == ['<section id="state">the state</section>']


async def test_a_batch_is_rendered_once_for_every_open_page_of_a_view(store: Repositories) -> None:  # noqa: F811
    view = RowsView()
    opened = Request({"type": "http", "headers": [], "query_string": b""})
    closing = anyio.Event()  # what sse-starlette sets when the server shuts down
    async with running(Feed(StoredEvents(store.events), poll_s=0.01)) as feed:
        pages = [_fragments(view, feed, opened, closing) for _ in range(3)]
        try:
            for page in pages:
                assert (await anext(page)).event == FRAGMENT_EVENT  # subscribed, the state sent
            await store.events.write_events([received(0, datetime.now(timezone.utc))])
            async with asyncio.timeout(DEADLINE_S):
                sent = [await anext(page) for page in pages]
            for item in sent:
                assert isinstance(item, bytes)
                assert '<tr id="event-0"><td>0</td></tr>' in json.loads(sse_data(item))
            assert sent[0] is sent[1] is sent[2], "three pages, one encoding"
            closing.set()  # the server shuts down: every open page's stream ends, no batch needed
            async with asyncio.timeout(DEADLINE_S):
                for page in pages:
                    with pytest.raises(StopAsyncIteration):
                        await anext(page)
        finally:
            for page in pages:
                await page.aclose()
    assert view.rendered == [0], "three pages, one render"


class SlowStateView(RowsView):
    """A view whose state renders, after the first time, only once ``go`` is set: a render of the
    team and the hazards that takes long on a busy console."""

    def __init__(self) -> None:
        super().__init__()
        self.snapshot = Shared(self._render, interval=0)
        self.renders = 0
        self.go = asyncio.Event()

    async def _render(self) -> list[str]:
        self.renders += 1
        if self.renders > 1:
            await self.go.wait()
        return [f'<section id="state">render {self.renders}</section>']


async def test_a_batchs_rows_wait_for_no_render_of_the_state(store: Repositories) -> None:  # noqa: F811
    view = SlowStateView()
    opened = Request({"type": "http", "headers": [], "query_string": b""})
    async with running(Feed(StoredEvents(store.events), poll_s=0.01)) as feed:
        page = _fragments(view, feed, opened, anyio.Event())
        try:
            assert (await anext(page)).event == FRAGMENT_EVENT  # subscribed, the state sent
            await store.events.write_events([received(0, datetime.now(timezone.utc))])
            async with asyncio.timeout(DEADLINE_S):
                rows = await anext(page)  # while the state's render is held
            assert json.loads(sse_data(rows)) == ['<tr id="event-0"><td>0</td></tr>']
            assert view.renders == 1 and not view.go.is_set()
            view.go.set()
            async with asyncio.timeout(DEADLINE_S):
                state = await anext(page)
            assert json.loads(sse_data(state)) == ['<section id="state">render 2</section>']
        finally:
            await page.aclose()
