"""Central's console shows each site: its link up or down, and what it forwarded."""

from __future__ import annotations

from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.site_report import report_to_central
from fleetbus.workers.site_status import site_view
from tests.console.support import Browser, running_console
from tests.factories import status
from tests.sites.pair import SitePair
from tests.support import wait_for


def test_the_dashboard_shows_each_site_link_and_forwards(pair: SitePair, browser: Browser) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with pair.site.worker(), pair.central.worker(), running_console(pair.central) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        explorer.publish_many([("status", status(80)) for _ in range(3)])
        browser.until(lambda: browser.text("#site-base1 td.forwarded") == "3", "three forwarded")
        browser.until(lambda: browser.text("#site-base1 td.link") == "up", "the link up")
        pair.link.cut()
        browser.until(lambda: browser.text("#site-base1 td.link") == "down", "the link down")


def test_the_dashboard_shows_what_waits_at_each_site_and_since_when(pair: SitePair, browser: Browser) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with running_console(pair.central) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        browser.until(lambda: browser.text("#site-base1 td.link") == "up", "the link up")
        browser.until(lambda: browser.text("#site-base1 td.since").endswith("ago"), "up since when")
        browser.until(lambda: browser.text("#site-base1 td.waiting") == "no report yet", "no report yet")
        pair.stop()  # the shovels stopped: the robot's events wait at the site
        explorer.publish_many([("status", status(80)) for _ in range(2)])
        wait_for(
            lambda: site_view(pair.site.api, pair.site.vhost, []).waiting == 2, what="counted at the site"
        )
        assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url)
        browser.until(lambda: browser.text("#site-base1 td.waiting").startswith("2 (reported"), "2 waiting")
        assert browser.text("#site-base1 td.hazard-states-waiting") == "0", "no hazard state made at the site"
        browser.until(lambda: browser.text("#site-base1 td.link") == "down", "the link down")
