"""Central's sites: which robots each site may forward for, and what each site forwarded.

A site (docs/guides/sites.md) is a fleetbus of its own on a team's network; its broker forwards
everything it accepted to central with a shovel. Central keeps here which robots live at which
site (a robot at one site at most), so that a forwarded event's claim to come from a site is
believed only for that site's own robots, and one record per forwarded event: its site, when it
was sent and received, and whether it came late.

Each site's list of robots has a **revision**, greater at each change of the list (a robot added,
taken away, moved to another site, removed at central): the list and its revision are one
document, changed by compare-and-set, so a change computed from a list read before another
change fails (:class:`StaleRevision`) instead of undoing it, on every database. Every downlink
message about a site's robots carries the revision it was made from. On a site, the newest
revision central's word on each robot had (:meth:`SiteRegistry.note_revision`) keeps an older
message from undoing a newer one.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.store.port import (
    BOOL,
    INTEGER,
    JSON,
    TEXT,
    TIME,
    Database,
    In,
    Index,
    Ne,
    NotIn,
    Range,
    Schema,
)


@dataclass(frozen=True)
class Forward:
    """One event central received through a site's uplink."""

    robot_id: str
    epoch: str
    seq: int
    site: str | None
    """The site the robot is assigned to; None when it is assigned to none (the claim is not believed)."""
    type: str
    sent_at: datetime
    received_at: datetime
    late: bool
    """Received more than ``FLEETBUS_LATE_AFTER_S`` after the robot sent it (the link was down)."""

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.robot_id, self.epoch, self.seq)


@dataclass(frozen=True)
class SiteSummary:
    site: str
    robots: tuple[str, ...]
    forwarded: int
    late: int
    newest_sent_at: datetime | None
    """The send time of the newest event central received from the site."""
    last_received_at: datetime | None
    """When central last received an event from the site."""


@dataclass(frozen=True)
class SiteList:
    """A site's robots, sorted, and the revision of that list (0: never changed)."""

    robots: tuple[str, ...]
    revision: int


@dataclass(frozen=True)
class ListChange:
    """What one :meth:`SiteRegistry.set_robots` made of one site's list."""

    site: str
    revision: int
    """The list's new revision."""
    robots: tuple[str, ...]
    joined: tuple[str, ...]
    """Robots the list did not have before."""
    left: tuple[str, ...]
    """Robots no longer on it (taken away, or moved to the site whose robots were set)."""


class StaleRevision(Exception):
    """A site's list changed since it was read: the change was not made."""

    def __init__(self, site: str, read: int) -> None:
        super().__init__(f"site {site}'s robots changed since they were read (at revision {read})")
        self.site = site


class SiteRegistry(abc.ABC):
    @abc.abstractmethod
    async def set_robots(
        self, site: str, robots: Collection[str], *, revision: int | None = None
    ) -> list[ListChange]:
        """Make ``site`` known with exactly these robots (a robot of another site moves here, and
        that site's list is changed too), each list's revision greater (:func:`next_revision`).
        ``revision``: only if ``site``'s list is still at that revision (as read), else
        :class:`StaleRevision` and nothing changed. What changed: ``site``'s list first, then each
        site a robot moved from."""

    @abc.abstractmethod
    async def robots_of(self, site: str) -> SiteList | None:
        """The site's robots and their list's revision, read together; None: no such site."""

    @abc.abstractmethod
    async def remove_site(self, site: str) -> None:
        """Forget the site and its robots (what it forwarded stays)."""

    @abc.abstractmethod
    async def sites(self) -> dict[str, tuple[str, ...]]:
        """Every site with its robots, sorted by name."""

    @abc.abstractmethod
    async def site_of(self, robots: Collection[str]) -> dict[str, str]:
        """The site of each of ``robots`` that has one."""

    @abc.abstractmethod
    async def record_forwards(self, forwards: Sequence[Forward]) -> None:
        """Keep each forward once (idempotent on its robot, epoch and sequence number)."""

    @abc.abstractmethod
    async def forwards(self, robot_id: str | None = None) -> list[Forward]:
        """The forwards recorded, by robot, epoch and sequence number."""

    @abc.abstractmethod
    async def summaries(self) -> list[SiteSummary]:
        """Each known site: its robots, how much it forwarded, the newest, by name."""

    @abc.abstractmethod
    async def put_report(self, report: SiteReport) -> bool:
        """Keep ``report`` as its site's newest unless one as new or newer is kept; whether it was."""

    @abc.abstractmethod
    async def reports(self) -> dict[str, SiteReport]:
        """Each site's newest report, by site."""

    @abc.abstractmethod
    async def note_revision(self, robot: str, revision: int) -> bool:
        """On a site: keep ``revision`` as that of central's newest word on ``robot`` unless a newer
        one is kept; whether it was (False: the message is older than one applied)."""


SITES = Schema(
    "sites",
    {"name": TEXT, "added_at": TIME, "revision": INTEGER.maybe, "robots": JSON.maybe},
    key=("name",),
)
"""A site, its list of robots and the list's revision (both null for a site stored before lists
had revisions: its robots are then those of :data:`SITE_ROBOTS`, at revision 0)."""
SITE_ROBOTS = Schema(
    "site_robots", {"robot_id": TEXT, "site": TEXT}, key=("robot_id",), indexes=(Index("site"),)
)
FORWARDS = Schema(
    "site_forwards",
    {
        "robot_id": TEXT,
        "epoch": TEXT,
        "seq": INTEGER,
        "site": TEXT.maybe,
        "type": TEXT,
        "sent_at": TIME,
        "received_at": TIME,
        "late": BOOL,
    },
    key=("robot_id", "epoch", "seq"),
    indexes=(Index("site", "sent_at"), Index("received_at")),
)
FORWARD_COUNTS = Schema(
    "site_forward_counts",
    {
        "site": TEXT,
        "forwarded": INTEGER,
        "late": INTEGER,
        "newest_sent_at": TIME,
        "last_received_at": TIME,
    },
    key=("site",),
)
"""Each site's forwards summed as they are recorded: what the dashboard and `fleetbus sites` show
read one row a site, however long the log of forwards (pruned by age) has grown."""
REPORTS = Schema("site_reports", {"site": TEXT, "at": TIME, "report": JSON}, key=("site",))
CENTRALS_WORD = Schema("site_robot_revisions", {"robot": TEXT, "revision": INTEGER}, key=("robot",))
"""On a site: the revision of the newest downlink message about each robot it applied."""


def next_revision(revision: int) -> int:
    """The revision after ``revision``: the time in microseconds since the epoch, or one more when
    that is not greater. Greater than every earlier one however the store was restored (from a
    copy whose revisions a site has passed already), as long as central's clock runs forward."""
    return max(revision + 1, time.time_ns() // 1000)


class Sites(SiteRegistry):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._sites = database.collection(SITES)
        self._robots = database.collection(SITE_ROBOTS)
        self._forwards = database.collection(FORWARDS)
        self._counts = database.collection(FORWARD_COUNTS)
        self._reports = database.collection(REPORTS)
        self._revisions = database.collection(CENTRALS_WORD)

    async def _list(self, doc: dict[str, Any]) -> SiteList:
        if doc["robots"] is None:  # stored before lists had revisions
            rows = await self._robots.find({"site": doc["name"]}, order=["robot_id"])
            return SiteList(tuple(row["robot_id"] for row in rows), 0)
        return SiteList(tuple(sorted(doc["robots"])), doc["revision"] or 0)

    async def _replace(self, doc: dict[str, Any], robots: Collection[str]) -> ListChange | None:
        """Compare-and-set: ``doc``'s list becomes ``robots`` unless it changed since ``doc`` was
        read (None then). One document, so atomic on every database."""
        old = await self._list(doc)
        new = tuple(sorted(set(robots)))
        where = {"name": doc["name"], "revision": doc["revision"]}
        revision = next_revision(old.revision)
        if not await self._sites.update(where, {"robots": list(new), "revision": revision}):
            return None
        joined = tuple(r for r in new if r not in old.robots)
        left = tuple(r for r in old.robots if r not in new)
        return ListChange(doc["name"], revision, new, joined, left)

    async def set_robots(
        self, site: str, robots: Collection[str], *, revision: int | None = None
    ) -> list[ListChange]:
        async def work() -> list[ListChange]:
            now = datetime.now(timezone.utc)
            await self._sites.insert([{"name": site, "added_at": now, "revision": 0, "robots": []}])
            while True:
                doc = await self._sites.get(site)
                assert doc is not None
                found = (await self._list(doc)).revision
                if revision is not None and found != revision:
                    raise StaleRevision(site, revision)
                changed = await self._replace(doc, robots)
                if changed is not None:
                    break
                if revision is not None:  # another change came in between
                    raise StaleRevision(site, revision)
            changes = [changed]
            for name in [doc["name"] for doc in await self._sites.find({"name": Ne(site)}, order=["name"])]:
                while (other := await self._sites.get(name)) is not None:  # the sites robots move from
                    kept = set((await self._list(other)).robots)
                    if not kept & set(robots):
                        break
                    if (moved := await self._replace(other, kept - set(robots))) is not None:
                        changes.append(moved)
                        break
            # the robots' index (a robot's site, for each forwarded event) follows the lists
            await self._robots.delete({"site": site, "robot_id": NotIn(robots)})
            for robot in robots:
                await self._robots.put({"robot_id": robot, "site": site})
            return changes

        return await self._database.transaction(work)

    async def robots_of(self, site: str) -> SiteList | None:
        async def read() -> SiteList | None:
            doc = await self._sites.get(site)
            return None if doc is None else await self._list(doc)

        return await self._database.snapshot(read)

    async def remove_site(self, site: str) -> None:
        async def work() -> None:
            await self._robots.delete({"site": site})
            await self._sites.delete({"name": site})

        await self._database.transaction(work)

    async def sites(self) -> dict[str, tuple[str, ...]]:
        async def read() -> dict[str, tuple[str, ...]]:
            docs = await self._sites.find(order=["name"])
            return {doc["name"]: (await self._list(doc)).robots for doc in docs}

        return await self._database.snapshot(read)

    async def site_of(self, robots: Collection[str]) -> dict[str, str]:
        if not robots:
            return {}
        found = await self._database.snapshot(
            lambda: self._robots.find({"robot_id": In(sorted(set(robots)))}), urgent=True
        )
        return {doc["robot_id"]: doc["site"] for doc in found}

    async def record_forwards(self, forwards: Sequence[Forward]) -> None:
        async def record() -> None:
            inserted = await self._forwards.insert([forward.__dict__ for forward in forwards])
            new = [forward for forward, fresh in zip(forwards, inserted, strict=True) if fresh]
            by_site: dict[str, list[Forward]] = {}
            for forward in new:  # a redelivered one is counted once, as it is kept once
                if forward.site is not None:
                    by_site.setdefault(forward.site, []).append(forward)
            for site, added in by_site.items():
                await self._count(site, added)

        await self._database.transaction(record)

    async def _count(self, site: str, added: Sequence[Forward]) -> None:
        newest_sent = max(forward.sent_at for forward in added)
        last_received = max(forward.received_at for forward in added)
        if await self._counts.get(site) is None:
            # the site's first count: from the log as it is (this batch in it), once
            where = {"site": site}
            every = await self._forwards.group("site", where, highest=["sent_at", "received_at"])
            late = await self._forwards.group("site", {**where, "late": True})
            group = every[site]
            row = {
                "site": site,
                "forwarded": group.count,
                "late": late[site].count if site in late else 0,
                "newest_sent_at": group.highest["sent_at"],
                "last_received_at": group.highest["received_at"],
            }
            if (await self._counts.insert([row]))[0]:
                return
            # another worker counted the site first: add this batch to its count
        late = sum(1 for forward in added if forward.late)
        await self._counts.update({"site": site}, {}, add={"forwarded": len(added), "late": late})
        await self._counts.update(
            {"site": site, "newest_sent_at": Range(lt=newest_sent)}, {"newest_sent_at": newest_sent}
        )
        await self._counts.update(
            {"site": site, "last_received_at": Range(lt=last_received)}, {"last_received_at": last_received}
        )

    async def forwards(self, robot_id: str | None = None) -> list[Forward]:
        where = {} if robot_id is None else {"robot_id": robot_id}
        return [
            Forward(**doc) for doc in await self._forwards.find(where, order=["robot_id", "epoch", "seq"])
        ]

    async def summaries(self) -> list[SiteSummary]:
        async def read() -> tuple[dict[str, tuple[str, ...]], list[dict[str, Any]]]:
            return await self.sites(), await self._counts.find()

        known, rows = await self._database.snapshot(read)
        counts = {row["site"]: row for row in rows}
        summaries = []
        for site, robots in known.items():
            row = counts.get(site)
            if row is None:
                summaries.append(SiteSummary(site, robots, 0, 0, None, None))
                continue
            summaries.append(
                SiteSummary(
                    site,
                    robots,
                    row["forwarded"],
                    row["late"],
                    row["newest_sent_at"],
                    row["last_received_at"],
                )
            )
        return summaries

    async def put_report(self, report: SiteReport) -> bool:
        doc = {"site": report.site, "at": report.at, "report": report.model_dump(mode="json")}
        return await self._reports.put(doc, where={"at": Range(lt=report.at)})

    async def reports(self) -> dict[str, SiteReport]:
        return {doc["site"]: SiteReport.model_validate(doc["report"]) for doc in await self._reports.find()}

    async def note_revision(self, robot: str, revision: int) -> bool:
        return await self._revisions.put(
            {"robot": robot, "revision": revision}, where={"revision": Range(le=revision)}
        )
