"""On a site: tell central what waits in the uplink and how the shovels fare
(:class:`~fleetbus.schemas.site_reports.SiteReport`), published to the site's ``<site>.status``
at central as the site's own account. While the link is down the report cannot go: central shows
the last one it got, with its age."""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping
from datetime import datetime, timezone

import pika

from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import forwarded_robots
from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.routing import site_status_exchange
from fleetbus.schemas.site_reports import SITE_REPORT_TYPE, SiteReport
from fleetbus.workers.account_use import in_use
from fleetbus.workers.site_status import site_view
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.team import TeamStore

log = logging.getLogger("fleetbus.sites")


def site_report(
    api: ManagementAPI,
    vhost: str,
    site: str,
    team: Collection[str] = (),
    in_use: Mapping[str, str] | None = None,
) -> SiteReport:
    """The site's links now, as ``fleetbus site status`` shows them, and the copies it has of the
    accounts central gave it (``team``: the robots of the site's team; ``in_use``: those in use at
    the site, with why). Central's copies are the robots whose events the site forwards, as the
    downlink's list of the site's robots judges them: a robot made at the site alone is in its team
    but not central's, and is left out."""
    link = site_view(api, vhost, team)
    accounts = sorted(forwarded_robots(api, vhost) & {user["name"] for user in api.list_users()})
    return SiteReport(
        site=site,
        at=datetime.now(timezone.utc),
        waiting=link.waiting,
        classes=link.classes or None,
        uplink=link.uplink.state,
        downlink=link.downlink.state,
        rejected=link.rejected,
        hazard_states_waiting=link.hazard_states_waiting,
        hazard_uplink=link.hazard_uplink.state if link.hazard_uplink else None,
        accounts=accounts,
        in_use={name: why for name, why in (in_use or {}).items() if name in accounts},
    )


async def team_in_use(robots: TeamStore, channels: ChannelStore) -> tuple[list[str], dict[str, str]]:
    """The robots of the site's team, and those of them in use at the site (with why)."""
    team = [robot.name for robot in await robots.robots()]
    held = {name: why for name in team if (why := await in_use(channels, name))}
    return team, held


def send_report(central_url: str, report: SiteReport) -> None:
    """Publish ``report`` at central (confirmed); raises when central cannot be reached."""
    connection = pika.BlockingConnection(pika_parameters(central_url))
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        channel.basic_publish(
            site_status_exchange(report.site),
            "",
            report.model_dump_json().encode(),
            pika.BasicProperties(content_type="application/json", type=SITE_REPORT_TYPE),
            mandatory=True,
        )
    finally:
        connection.close()


def report_to_central(
    api: ManagementAPI,
    vhost: str,
    site: str,
    central_url: str,
    team: Collection[str] = (),
    in_use: Mapping[str, str] | None = None,
) -> bool:
    """Measure and send one report; False (logged, without the URL's password) when it could not go."""
    report = site_report(api, vhost, site, team, in_use)
    try:
        send_report(central_url, report)
    except Exception as error:  # the link is down: the next report tries again
        log.warning("site %s: report to central not sent (%s)", site, type(error).__name__)
        return False
    return True
