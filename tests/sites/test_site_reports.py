"""Central sees what waits at each site: the site reports its uplink and links to central, and
`fleetbus sites` shows the newest report with its age (stale while the link is down)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from datetime import datetime, timezone
from urllib.parse import urlsplit

import pika

from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.routing import HAZARD_UPLINK_QUEUE, RobotKind, site_status_exchange
from fleetbus.schemas.site_reports import SiteReport, UplinkDepth
from fleetbus.workers.site_report import report_to_central, site_report
from fleetbus.workers.site_status import SiteLink, near_full, site_view
from tests.factories import hazard, status
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_cli import fleetbus


def _row(pair: SitePair) -> dict:
    shown = fleetbus(pair.central, "sites", "--json")
    assert shown.returncode == 0, shown.stderr
    [row] = [row for row in json.loads(shown.stdout) if row["site"] == pair.name]
    return row


def test_central_shows_what_waits_at_the_site_and_how_old_that_is(pair: SitePair) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    row = _row(pair)
    assert row["waiting"] is None and row["reported_at"] is None, "no report yet"

    pair.stop()  # the shovels stopped: the robot's events wait in the uplink
    # their connections to central close after the shovels are deleted, not with the deletion
    wait_for(lambda: not _row(pair)["link_up"], what="the shovels' connections closed at central")
    explorer.publish_many([("status", status(80)) for _ in range(3)])
    wait_for(lambda: pair.uplink_waiting() == 3, what="three waiting at the site")
    # as `fleetbus site status` counts them (the management API's figures lag a few seconds)
    wait_for(lambda: site_view(pair.site.api, pair.site.vhost, []).waiting == 3, what="counted at the site")
    assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url)
    row = _row(pair)
    assert row["waiting"] == 3 and row["reported_at"] is not None
    assert row["report_age_s"] < 60

    pair.link.cut()  # no report can go now: central keeps showing the last one, older each time
    assert not report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url)
    # the link shows down once the management API no longer lists the report's closed connection
    later = wait_for(
        lambda: (r := _row(pair))["report_age_s"] > row["report_age_s"] and not r["link_up"] and r,
        what="the age growing, the link down",
    )
    assert later["waiting"] == 3 and later["reported_at"] == row["reported_at"]

    shown = fleetbus(pair.central, "sites")
    assert shown.returncode == 0, shown.stderr
    assert "waiting" in shown.stdout and "ago" in shown.stdout


def test_site_apply_reports_to_central(pair: SitePair) -> None:
    env = {**os.environ, **pair.site.worker_env(), "FLEETBUS_CENTRAL_URL": pair.central_url, "COLUMNS": "200"}
    applied = subprocess.run(
        [sys.executable, "-m", "fleetbus", "site", "apply", "--once", "--name", pair.name],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert applied.returncode == 0, applied.stderr
    assert "not reporting" not in applied.stdout
    assert pair.account is not None
    password = urlsplit(pair.account.amqp_url).password or ""
    assert password not in applied.stdout + applied.stderr, "the password is never shown"
    row = _row(pair)
    assert row["waiting"] == 0 and row["reported_at"] is not None


def test_central_shows_the_hazard_states_waiting_at_the_site(pair: SitePair) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with pair.site.worker():
        pair.stop()  # the hazard states' shovel too: what the site's worker makes waits
        # their connections to central close after the shovels are deleted, not with the deletion
        wait_for(lambda: not _row(pair)["link_up"], what="the shovels' connections closed at central")
        explorer.publish("hazard", hazard(0))  # held (no warden localised): a first state

        # counted as the report counts them (the management API's figures lag a few seconds)
        def counted() -> SiteLink | None:
            view = site_view(pair.site.api, pair.site.vhost, [])
            return view if view.hazard_states_waiting and view.waiting else None

        view = wait_for(counted, what="the hazard event and a hazard state counted at the site")
        waiting = view.hazard_states_waiting
        assert pair.site.ready_messages(HAZARD_UPLINK_QUEUE) == waiting
        assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url)
    row = _row(pair)
    assert row["hazard_states_waiting"] == waiting and row["waiting"] == 1, "the hazard event and its state"

    shown = fleetbus(pair.central, "sites")
    assert shown.returncode == 0, shown.stderr
    assert "states" in shown.stdout


def test_central_alerts_on_a_class_near_its_bound() -> None:
    report = SiteReport(
        site="base1",
        at=datetime.now(timezone.utc),
        waiting=180_010,
        uplink="starting",
        downlink="starting",
        classes={
            "hazards": UplinkDepth(waiting=10, bound=100_000, overflow="reject-publish"),
            "telemetry": UplinkDepth(waiting=180_000, bound=200_000, overflow="drop-head"),
        },
    )
    assert near_full(report, 0.8) == ("telemetry 90% of 200,000 (oldest dropped)",)
    assert near_full(report, 0.95) == ()


def test_a_report_naming_another_site_is_not_kept_as_that_sites(pair: SitePair) -> None:
    """Only a site's account may write its status exchange, so the exchange names the site: a
    report that names another (a site's fleetbus at fault, or its account misused) is skipped,
    and the other site's reports stay its own."""
    honest = site_report(pair.site.api, pair.site.vhost, pair.name)
    forged = honest.model_copy(update={"site": "other-site", "waiting": 0})
    connection = pika.BlockingConnection(pika_parameters(pair.central_url))
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for report in (forged, honest):  # the site's own report after it: proof both were read
            body = report.model_dump_json().encode()
            channel.basic_publish(site_status_exchange(pair.name), "", body, mandatory=True)
    finally:
        connection.close()
    wait_for(lambda: _row(pair)["reported_at"] is not None, what="the site's own report kept")
    reports = pair.central.with_store(lambda store: store.sites.reports())
    assert set(reports) == {pair.name}
