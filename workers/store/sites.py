"""Central's sites: which robots each site may forward for, and what each site forwarded.

A site (docs/guides/sites.md) is a fleetbus of its own on a team's network; its broker forwards
everything it accepted to central with a shovel. Central keeps here which robots live at which
site (a robot at one site at most), so that a forwarded event's claim to come from a site is
believed only for that site's own robots, and one record per forwarded event: its site, when it
was sent and received, and whether it came late.
"""

from __future__ import annotations

import abc
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
    Group,
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


class SiteRegistry(abc.ABC):
    @abc.abstractmethod
    async def set_robots(self, site: str, robots: Collection[str]) -> None:
        """Make ``site`` known with exactly these robots (a robot of another site moves here)."""

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


SITES = Schema("sites", {"name": TEXT, "added_at": TIME}, key=("name",))
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
    indexes=(Index("site", "sent_at"),),
)
REPORTS = Schema("site_reports", {"site": TEXT, "at": TIME, "report": JSON}, key=("site",))


class Sites(SiteRegistry):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._sites = database.collection(SITES)
        self._robots = database.collection(SITE_ROBOTS)
        self._forwards = database.collection(FORWARDS)
        self._reports = database.collection(REPORTS)

    async def set_robots(self, site: str, robots: Collection[str]) -> None:
        async def work() -> None:
            await self._sites.insert([{"name": site, "added_at": datetime.now(timezone.utc)}])
            await self._robots.delete({"site": site, "robot_id": NotIn(robots)})
            for robot in robots:
                await self._robots.put({"robot_id": robot, "site": site})

        await self._database.transaction(work)

    async def remove_site(self, site: str) -> None:
        async def work() -> None:
            await self._robots.delete({"site": site})
            await self._sites.delete({"name": site})

        await self._database.transaction(work)

    async def sites(self) -> dict[str, tuple[str, ...]]:
        async def read() -> dict[str, tuple[str, ...]]:
            found: dict[str, list[str]] = {doc["name"]: [] for doc in await self._sites.find()}
            for doc in await self._robots.find(order=["robot_id"]):
                found.setdefault(doc["site"], []).append(doc["robot_id"])
            return {name: tuple(found[name]) for name in sorted(found)}

        return await self._database.snapshot(read)

    async def site_of(self, robots: Collection[str]) -> dict[str, str]:
        if not robots:
            return {}
        found = await self._database.snapshot(
            lambda: self._robots.find({"robot_id": In(sorted(set(robots)))}), urgent=True
        )
        return {doc["robot_id"]: doc["site"] for doc in found}

    async def record_forwards(self, forwards: Sequence[Forward]) -> None:
        await self._forwards.insert([forward.__dict__ for forward in forwards])

    async def forwards(self, robot_id: str | None = None) -> list[Forward]:
        where = {} if robot_id is None else {"robot_id": robot_id}
        return [
            Forward(**doc) for doc in await self._forwards.find(where, order=["robot_id", "epoch", "seq"])
        ]

    async def summaries(self) -> list[SiteSummary]:
        async def read() -> tuple[dict[str, tuple[str, ...]], dict[Any, Group], dict[Any, Group]]:
            forwarded = {"site": Ne(None)}
            counts = await self._forwards.group("site", forwarded, highest=["sent_at", "received_at"])
            late = await self._forwards.group("site", {**forwarded, "late": True})
            return await self.sites(), counts, late

        known, counts, late = await self._database.snapshot(read)
        summaries = []
        for site, robots in known.items():
            group = counts.get(site, Group(0, {"sent_at": None, "received_at": None}))
            late_ones = late[site].count if site in late else 0
            newest = group.highest
            summaries.append(
                SiteSummary(site, robots, group.count, late_ones, newest["sent_at"], newest["received_at"])
            )
        return summaries

    async def put_report(self, report: SiteReport) -> bool:
        doc = {"site": report.site, "at": report.at, "report": report.model_dump(mode="json")}
        return await self._reports.put(doc, where={"at": Range(lt=report.at)})

    async def reports(self) -> dict[str, SiteReport]:
        return {doc["site"]: SiteReport.model_validate(doc["report"]) for doc in await self._reports.find()}
