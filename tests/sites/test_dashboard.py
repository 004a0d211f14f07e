"""Central's console shows each site: its link up or down, and what it forwarded."""

from __future__ import annotations

from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import Browser, running_console
from tests.factories import status
from tests.sites.pair import SitePair


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
