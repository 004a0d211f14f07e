"""Central's queue of the sites' reports is bounded, and the API's alerts read it themselves: with
no dashboard open, nobody else takes the reports in (real broker)."""

from __future__ import annotations

import asyncio
from datetime import datetime, timezone

from fleetbus.api.service import open_service
from fleetbus.api.services.alerts import AlertKind
from fleetbus.broker.sites import central_site_topology
from fleetbus.broker.topology import declare_with_url
from fleetbus.schemas.routing import SITE_REPORTS_QUEUE, site_status_exchange
from fleetbus.schemas.site_reports import SiteReport, UplinkDepth
from tests.support import Bus, wait_for
from tests.test_queue_bounds import bounded_by, overflow_counts

SITE = "base1"


def report(telemetry_waiting: int) -> SiteReport:
    return SiteReport(
        site=SITE,
        at=datetime.now(timezone.utc),
        waiting=telemetry_waiting,
        uplink="running",
        downlink="running",
        classes={"telemetry": UplinkDepth(waiting=telemetry_waiting, bound=200_000, overflow="drop-head")},
    )


def send_reports(bus: Bus, reports: list[SiteReport]) -> None:
    """As the site's report loop sends them: to its status exchange at central."""
    asyncio.run(declare_with_url(bus.admin_url, [central_site_topology(SITE)]))
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        for each in reports:
            channel.basic_publish(site_status_exchange(SITE), "", each.model_dump_json().encode())


def waiting_reports(bus: Bus) -> int:
    with bus.admin_channel() as channel:
        return int(channel.queue_declare(SITE_REPORTS_QUEUE, passive=True).method.message_count)


def test_the_reports_nobody_reads_are_bounded_and_the_dropped_counted(bus: Bus) -> None:
    bus.settings = bus.settings.updated(site_reports_max=("3",))
    bus.service_accounts()  # `fleetbus setup`: the policies
    send_reports(bus, [report(n) for n in range(5)])
    wait_for(lambda: bounded_by(bus, SITE_REPORTS_QUEUE, "fleetbus-site-reports"), what="the policy")
    with bus.worker():
        wait_for(lambda: overflow_counts(bus).get(f"{SITE_REPORTS_QUEUE} maxlen") == 2, what="two counted")
    assert waiting_reports(bus) == 3, "the newest three wait"


def test_the_api_alerts_on_the_reports_waiting_in_the_broker(bus: Bus) -> None:
    bus.service_accounts()
    bus.with_store(lambda store: store.sites.set_robots(SITE, ()))  # `fleetbus sites add`, in the store
    send_reports(bus, [report(0), report(190_000)])  # the newest: telemetry at 95 % of its bound

    async def check() -> list[str]:
        async with open_service(bus.settings, bus.admin_url, bus.endpoint.management_url) as service:
            raised = await service.alerts.check()
            return [f"{alert.kind} {alert.subject}" for alert in raised]

    assert asyncio.run(check()) == [f"{AlertKind.UPLINK_NEAR_FULL.value} site {SITE}"]
    assert waiting_reports(bus) == 0, "the alerts took the reports in"
