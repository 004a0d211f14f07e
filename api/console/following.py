"""What a console user may follow live: what its broker stream (``<user>.stream``, the queue
``fleetbus tail`` reads) receives, told from the store's copy of each event.

Operators and supervisors have a stream (their broker accounts are operator accounts,
:func:`fleetbus.api.services.accounts.broker_role`). It is bound to the beacon exchange, so it receives
every robot's beacons that passed the broker's header check, and, while an operator has a robot
mounted, to that robot's events exchange (:func:`fleetbus.broker.mounts.mount_bindings`). The
workers store an event only when it came through the exchange its type is published to, and keep
that exchange, so the stored copy says which binding brought it. Every other account has no stream
and follows nothing.

The console shows what the store holds: a message the workers refused is in the user's stream but
not here (Messages' search and trace show it).
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

from fleetbus.api.console.templating import fragment
from fleetbus.api.services.accounts import User, broker_role
from fleetbus.api.services.channels import Channels, Mount
from fleetbus.api.services.stored_events import EventRecord, StoredEvents
from fleetbus.broker.accounts import Role
from fleetbus.broker.mounts import mount_bindings
from fleetbus.schemas.routing import beacon_exchange, stream_queue
from fleetbus.workers.recorder.summary import compact, shorten

SUMMARY_WIDTH = 140


def has_stream(user: User) -> bool:
    return broker_role(user.role) is Role.OPERATOR


def mounted_sources(user: User, mounts: Sequence[Mount]) -> dict[str, Mount]:
    """The robots' events exchanges the user's stream is bound to by a mount, with that mount."""
    return {
        binding.source: mount
        for mount in mounts
        for binding in mount_bindings(mount.robot, mount.operator)
        if binding.queue == stream_queue(user.name)
    }


def follows(user: User, mounts: Sequence[Mount], record: EventRecord) -> bool:
    """Whether ``record`` reached the user's stream: a beacon, or an event of a robot the user has
    mounted, received since the mount (a mount made later does not bind what came before it)."""
    if not has_stream(user):
        return False
    if record.exchange == beacon_exchange(record.robot_id):
        return True
    mount = mounted_sources(user, mounts).get(record.exchange)
    return mount is not None and record.received_at >= mount.mounted_at


class MountBook:
    """The current mounts, read from the store once per batch of the live feed and shared by every
    open page. A batch's mounts are read after its events were, so a mount made before one of them
    was published is among them; a mount ended since is not (its robot is no longer followed)."""

    def __init__(self, channels: Channels) -> None:
        self._channels = channels
        self._lock = asyncio.Lock()
        self._batch: object = None
        self._mounts: list[Mount] | None = None

    async def for_batch(self, records: list[EventRecord]) -> list[Mount]:
        """The mounts as of this batch (the feed hands every page the same list object)."""
        async with self._lock:
            if records is not self._batch or self._mounts is None:
                self._mounts = await self._channels.mounts()
                self._batch = records
            return self._mounts

    async def latest(self) -> list[Mount]:
        async with self._lock:
            if self._mounts is None:
                self._mounts = await self._channels.mounts()
            return self._mounts


def summary(record: EventRecord) -> str:
    """What ``fleetbus tail`` prints of a message: its sequence number and body."""
    return shorten(f"seq {record.seq} {compact(record.body)}", SUMMARY_WIDTH)


def newest_first(records: Sequence[EventRecord]) -> list[EventRecord]:
    return sorted(records, key=lambda r: (r.received_at, r.key), reverse=True)


class TailView:
    """The live tail of one user's page: the rows of what its stream receives, and whom it follows."""

    def __init__(self, user: User, book: MountBook, rows: int) -> None:
        self._user = user
        self._book = book
        self._rows = rows

    async def snapshot(self) -> list[str]:
        mounts = await self._book.latest() if has_stream(self._user) else []
        robots = sorted(mounted_sources(self._user, mounts).values(), key=lambda m: m.robot)
        return [
            fragment("messages/following.html", user=self._user, stream=has_stream(self._user), mounts=robots)
        ]

    async def events(self, records: list[EventRecord]) -> list[str]:
        if not has_stream(self._user):
            return []
        mounts = await self._book.for_batch(records)  # a tick's empty batch too: snapshot() shows them
        shown = [record for record in records if follows(self._user, mounts, record)]
        return [self.row(record) for record in shown[-self._rows :]]

    def row(self, record: EventRecord) -> str:
        return fragment("messages/tail_row.html", event=record, summary=summary(record))

    async def recent(self, events: StoredEvents) -> list[str]:
        """The newest rows the stream received, for the page as first rendered (newest first)."""
        if not has_stream(self._user):
            return []
        mounts = await self._book.latest()
        found = {record.key: record for record in await events.newest(self._rows, type="beacon")}
        for mount in mounted_sources(self._user, mounts).values():
            found.update((r.key, r) for r in await events.newest(self._rows, robot_id=mount.robot))
        shown = [
            record for record in newest_first(list(found.values())) if follows(self._user, mounts, record)
        ]
        return [self.row(record) for record in shown[: self._rows]]
