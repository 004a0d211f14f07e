"""Central's links to its sites as the console's dashboard shows them: each known site's robots
and what it forwarded, and each site's newest report (those waiting in the broker taken into the
store first). Elsewhere than on central there are none."""

from __future__ import annotations

import logging

from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.site_report_collector import collect_site_reports
from fleetbus.workers.store.sites import SiteRegistry, SiteSummary

__all__ = ["SiteLinks", "SiteReport", "SiteSummary"]

log = logging.getLogger("fleetbus.console")  # the dashboard logged it under this name


class SiteLinks:
    def __init__(self, sites: SiteRegistry, admin_url: str, alert_at: float) -> None:
        """``alert_at``: the share of an uplink's bound at which a report is logged as an alert."""
        self._sites = sites
        self._admin_url = admin_url
        self._alert_at = alert_at

    async def summaries(self) -> list[SiteSummary]:
        """Each known site: its robots, how much it forwarded, the newest, by name."""
        return await self._sites.summaries()

    async def reports(self) -> dict[str, SiteReport]:
        """Each site's newest report, by site; the broker away, the stored ones (aged)."""
        try:
            await collect_site_reports(self._admin_url, self._sites, alert_at=self._alert_at)
        except Exception as error:  # the broker is away: the stored reports still show, aged
            log.warning("site reports not collected: %s", type(error).__name__)
        return await self._sites.reports()
