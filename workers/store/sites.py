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
from datetime import datetime

from fleetbus.schemas.site_reports import SiteReport


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
