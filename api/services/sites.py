"""The sites as central and a site see them, for the command line, the HTTP API and the console: on central,
each site's link, what it forwarded and its newest report (``fleetbus sites``), and the missions a
site is sent again (``fleetbus sites sync``); on a site, the robots of its team and those in use
there (``fleetbus site status``, the reports to central)."""

from __future__ import annotations

import asyncio
import logging
from datetime import datetime, timezone

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.site_report import team_in_use
from fleetbus.workers.site_report_collector import collect_site_reports
from fleetbus.workers.site_status import SiteRow, central_view
from fleetbus.workers.sites import mission_changes, send_to_sites
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.missions import MissionStore
from fleetbus.workers.store.sites import SiteRegistry, SiteSummary
from fleetbus.workers.store.team import TeamStore

__all__ = ["SiteReport", "SiteRow", "SiteSummary", "SiteTeam", "Sites"]

log = logging.getLogger("fleetbus.sites")


class Sites:
    """Central's sites."""

    def __init__(self, sites: SiteRegistry, missions: MissionStore, admin_url: str, alert_at: float) -> None:
        """``admin_url``: central's broker, where the sites' reports wait and the missions go;
        ``alert_at``: the share of an uplink class's bound that is near full."""
        self._sites = sites
        self._missions = missions
        self._admin_url = admin_url
        self._alert_at = alert_at

    async def summaries(self) -> list[SiteSummary]:
        """Each known site: its robots, how much it forwarded, the newest, by name."""
        return await self._sites.summaries()

    async def collect(self) -> int:
        """Take the reports waiting in the broker into the store (each site's newest is kept); how
        many. With no site known, none can wait: the broker is not asked."""
        if not await self._sites.sites():
            return 0
        return await collect_site_reports(self._admin_url, self._sites, alert_at=self._alert_at)

    async def reports(self) -> dict[str, SiteReport]:
        """Each site's newest report, those waiting in the broker taken into the store first; the
        broker away, the stored ones (aged)."""
        try:
            await self.collect()
        except Exception as error:  # the broker is away: the stored reports still show, aged
            log.warning("site reports not collected: %s", type(error).__name__)
        return await self._sites.reports()

    async def view(self, management: ManagementAPI) -> list[SiteRow]:
        """Each site: its link (``management``: central's broker's management API), what it
        forwarded, how far behind central is, and its newest report."""
        reports = await self.reports()
        summaries = await self.summaries()
        vhost, now = vhost_of(self._admin_url), datetime.now(timezone.utc)
        return await asyncio.to_thread(
            central_view, management, vhost, summaries, now, reports, self._alert_at
        )

    async def send_missions(self, site: str) -> int:
        """Send ``site`` every mission it is sent, as central's store has them; how many."""
        missions = await mission_changes(self._missions, site)
        await asyncio.to_thread(send_to_sites, self._admin_url, [site], missions)
        return len(missions)


class SiteTeam:
    """On a site: the robots of its team."""

    def __init__(self, team: TeamStore, channels: ChannelStore) -> None:
        self._team = team
        self._channels = channels

    async def names(self) -> list[str]:
        return [robot.name for robot in await self._team.robots()]

    async def in_use(self) -> tuple[list[str], dict[str, str]]:
        """The robots of the team, and those of them in use at the site (with why)."""
        return await team_in_use(self._team, self._channels)
