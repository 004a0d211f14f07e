"""At central: take the sites' reports from ``fleetbus.site-reports`` into the store (each site's
newest is kept), acknowledging each only once it is stored."""

from __future__ import annotations

import logging

from aiormq.exceptions import ChannelNotFoundEntity
from pydantic import ValidationError

from fleetbus.broker.tls import aio_connect
from fleetbus.schemas.routing import SITE_REPORTS_QUEUE, site_of_status_exchange
from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.site_status import near_full
from fleetbus.workers.store.sites import SiteRegistry

log = logging.getLogger("fleetbus.sites")


async def collect_site_reports(
    admin_url: str, sites: SiteRegistry, limit: int = 10_000, alert_at: float = 0.8
) -> int:
    """Store what waits in the reports queue (up to ``limit``); how many were read. A report that
    does not parse, or names another site than the one whose exchange it came by, is logged and
    counted as read; one whose uplink is near full (``alert_at`` of a
    class's bound) is logged as an alert."""
    read = 0
    connection = await aio_connect(admin_url)
    try:
        channel = await connection.channel()
        try:
            queue = await channel.get_queue(SITE_REPORTS_QUEUE)
        except ChannelNotFoundEntity:
            return 0  # no site added yet
        while read < limit:
            message = await queue.get(fail=False)
            if message is None:
                break
            read += 1
            # only a site's account may write its status exchange: the exchange names the site
            site = site_of_status_exchange(message.exchange or "")
            try:
                report = SiteReport.model_validate_json(message.body)
            except ValidationError as error:
                log.error("a site report that does not parse, skipped: %s", error)
            else:
                if report.site != site:
                    log.error(
                        "a site report that came by %r names site %r, skipped", message.exchange, report.site
                    )
                else:
                    await sites.put_report(report)
                    if full := near_full(report, alert_at):
                        log.warning("alert: site %s's uplink is near full: %s", site, "; ".join(full))
            await message.ack()
    finally:
        await connection.close()
    return read
