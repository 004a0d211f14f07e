"""The console's live feed: one reader of the store per API process, fanned out to every open page.

The reader asks the store for the events received since its cursor every ``poll_s`` seconds and
hands each batch to every subscriber. Pages never read the broker: what they show is what the
store holds, so a browser that reconnects with the last event id it saw is sent, from the store,
everything it missed.

Workers write concurrently, so an event received a moment earlier may be committed a moment
later than one already read. The reader therefore looks again before its cursor, at the keys only
(an index read), and reads the events from the oldest key it has not handed out yet (a bounded set
of keys), usually just the new ones: at every poll from ``recent`` before its cursor (a write held
up by another's commit), and once a tick from ``overlap`` before it (a write held up longer). Each
look reads every key of its window, so looking ``overlap`` back at every poll would read
``rate x overlap / poll_s`` keys a second (30,000 with 600 events a second). Fragments are keyed by
the event, so a browser shown an event twice shows it once. An event whose write was held up for
longer than ``overlap`` (the store was down and the worker retried, or the machine overloaded) is
not streamed: pages show it when they are next loaded.

A subscriber that does not keep up (its queue of ``queue_size`` batches is full) is dropped: its
page's stream ends and the browser reconnects with its last event id. Drops are counted
(:attr:`Feed.dropped`) and shown on the dashboard.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import OrderedDict
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone

from fleetbus.api.services.stored_events import EventRecord, StoredEvents, StoreError, from_micros, to_micros
from fleetbus.settings import Settings

log = logging.getLogger("fleetbus.api.console")


def cursor_of(moment: datetime) -> str:
    """An SSE event id: the receive time, in microseconds since the epoch."""
    return str(to_micros(moment))


def moment_of(event_id: str | None) -> datetime | None:
    """The receive time an SSE event id names; ``None`` for no id or one that is not ours."""
    if not event_id or not event_id.isdigit():
        return None
    return from_micros(int(event_id))


@dataclass(frozen=True)
class Batch:
    """New events (possibly none: a tick, on which pages refresh what they show of the state)."""

    events: list[EventRecord]
    cursor: str
    rendered: dict[int, tuple[object, list[str]]] = field(default_factory=dict, compare=False, repr=False)
    """What each live view made of ``events`` (by the view's id, the view kept with it), so that
    a view's open pages render a batch once between them (:func:`.live.events_of`)."""
    encoded: dict[tuple[str, ...], bytes] = field(default_factory=dict, compare=False, repr=False)
    """The server-sent events made of this batch, by their fragments: pages sent the same
    fragments share one encoding (:func:`.live.encoded`)."""


@dataclass(eq=False)
class Subscription:
    queue: asyncio.Queue[Batch | None]
    dropped: bool = False


@dataclass
class Feed:
    events: StoredEvents
    poll_s: float = 0.1
    tick_s: float = 1.0
    overlap: timedelta = timedelta(seconds=5)
    recent: timedelta = timedelta(seconds=1)
    """How far back before its cursor the reader looks at every poll (``overlap``: once a tick)."""
    queue_size: int = 64
    batch_limit: int = 1000
    remembered: int = 20_000
    """How many keys of recently handed-out events are kept to skip them when read again."""
    dropped: int = 0
    """Subscribers dropped for not keeping up since the process started."""
    store_errors: int = 0
    watcher_errors: int = 0
    """Batches a watcher raised on (a bug): logged, and the other watchers and the pages still get them."""
    _cursor: datetime = field(default_factory=lambda: datetime.now(timezone.utc))
    _seen: OrderedDict[tuple[str, str, int], None] = field(default_factory=OrderedDict)
    _subscribers: set[Subscription] = field(default_factory=set)
    _watchers: list[Callable[[list[EventRecord]], None]] = field(default_factory=list)

    @property
    def cursor(self) -> str:
        return cursor_of(self._cursor)

    @property
    def subscribers(self) -> int:
        return len(self._subscribers)

    async def run(self) -> None:
        """Read and hand out until cancelled. A store that does not answer is retried next poll."""
        loop = asyncio.get_running_loop()
        next_tick = next_full = loop.time() + self.tick_s
        while True:
            full = loop.time() >= next_full
            if full:
                next_full = loop.time() + self.tick_s
            try:
                fresh = await self._read(self.overlap if full else min(self.recent, self.overlap))
            except StoreError as error:
                self.store_errors += 1
                log.warning("console feed: the store did not answer (%s); trying again", error)
                fresh = []
            except Exception:  # never end: every live page waits on this feed
                self.store_errors += 1
                log.exception("console feed: reading the store failed; trying again")
                fresh = []
            if fresh:
                self._watch(fresh)
            if fresh or loop.time() >= next_tick:
                self._publish(Batch(fresh, self.cursor))
                next_tick = loop.time() + self.tick_s
            await asyncio.sleep(self.poll_s)

    def _watch(self, fresh: list[EventRecord]) -> None:
        for watcher in self._watchers:
            try:
                watcher(fresh)
            except Exception:  # never end: every live page waits on this feed
                self.watcher_errors += 1
                log.exception(
                    "console feed: %r failed on a batch of %d events; going on", watcher, len(fresh)
                )

    async def _read(self, back: timedelta) -> list[EventRecord]:
        fresh: list[EventRecord] = []
        since = await self._first_unseen(self._cursor - back)
        if since is None:
            return fresh
        while True:
            found = await self.events.received_since(since, self.batch_limit)
            for record in found:
                if record.key not in self._seen:
                    self._remember(record.key)
                    self._cursor = max(self._cursor, record.received_at)
                    fresh.append(record)
            if len(found) < self.batch_limit or found[-1].received_at == since:
                return fresh
            since = found[-1].received_at  # a full page: read on from where it ended

    async def _first_unseen(self, since: datetime) -> datetime | None:
        """When the first event received since ``since`` not handed out yet was received."""
        while True:
            keys = await self.events.keys_received_since(since, self.batch_limit)
            for received in keys:
                if received.key not in self._seen:
                    return received.received_at
            if len(keys) < self.batch_limit or keys[-1].received_at == since:
                return None
            since = keys[-1].received_at

    def _remember(self, key: tuple[str, str, int]) -> None:
        self._seen[key] = None
        while len(self._seen) > self.remembered:
            self._seen.popitem(last=False)

    def _publish(self, batch: Batch) -> None:
        for subscription in list(self._subscribers):
            if subscription.queue.qsize() >= self.queue_size:
                self._drop(subscription)
            else:
                subscription.queue.put_nowait(batch)

    def _drop(self, subscription: Subscription) -> None:
        self._subscribers.discard(subscription)
        subscription.dropped = True
        self.dropped += 1
        subscription.queue.put_nowait(None)
        log.warning("console feed: a page did not keep up and was dropped (it reconnects)")

    def watch(self, watcher: Callable[[list[EventRecord]], None]) -> None:
        """Call ``watcher`` with every batch of new events, before the pages get it,
        for as long as the process runs: how state kept in memory (the newest status of each robot)
        follows the store without a read of its own. It must be quick and should not raise (what
        it raises is logged and counted in :attr:`watcher_errors`, and the feed goes on)."""
        self._watchers.append(watcher)

    @contextlib.asynccontextmanager
    async def subscribe(self) -> AsyncIterator[Subscription]:
        # one slot kept for the end-of-stream marker a dropped subscriber is sent
        subscription = Subscription(asyncio.Queue(self.queue_size + 1))
        self._subscribers.add(subscription)
        try:
            yield subscription
        finally:
            self._subscribers.discard(subscription)

    async def missed(self, since: datetime, limit: int) -> list[EventRecord] | None:
        """What a page that saw everything up to ``since`` may have missed, from the store: the
        events received since (``None`` when there are ``limit`` or more), after those received in
        the ``overlap`` before it (committed late, they may be new to the page too)."""
        after = await self.events.received_since(since, limit)
        if len(after) >= limit:
            return None
        around = await self.events.received_since(since - self.overlap, limit)
        return [record for record in around if record.received_at < since] + after


@contextlib.asynccontextmanager
async def running(feed: Feed) -> AsyncIterator[Feed]:
    """``feed`` reading the store until the ``with`` ends."""
    task = asyncio.create_task(feed.run(), name="console-feed")
    task.add_done_callback(_ended)
    try:
        yield feed
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def _ended(task: asyncio.Task[None]) -> None:
    """Said at once: the pages' pings go on, so a browser would show a frozen page as connected."""
    if not task.cancelled():
        error = task.exception()
        log.error("console feed ended (%r): live pages get no more updates", error, exc_info=error)


@contextlib.asynccontextmanager
async def running_feed(events: StoredEvents, settings: Settings) -> AsyncIterator[Feed]:
    """The process's feed, reading the store until the app stops."""
    feed = Feed(
        events,
        poll_s=settings.console_poll_s,
        tick_s=settings.console_tick_s,
        overlap=timedelta(seconds=settings.console_overlap_s),
        queue_size=settings.console_queue,
    )
    async with running(feed):
        yield feed
