"""Central's accounts reach the site: a robot registered centrally logs in to its site with the
password central gave it, and works there."""

from __future__ import annotations

from urllib.parse import unquote, urlsplit

from fleetbus.broker.accounts import Account, Role, url_for
from fleetbus.schemas.routing import DOWNLINK_QUEUE, RobotKind
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_cli import fleetbus


def test_a_robot_registered_centrally_works_at_its_site(pair: SitePair) -> None:
    central_account = pair.central.add("warden5", kind=RobotKind.WARDEN)
    pair.site.accounts.append("warden5")  # made at the site by the downlink; removed after the test
    assert pair.site.api.get_user("warden5") is None
    added = fleetbus(pair.central, "sites", "robots", "base1", "--add", "warden5")
    assert added.returncode == 0, added.stderr
    assert "sent base1 the accounts of warden5" in added.stdout
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1, what="the account through the downlink")
    applied = fleetbus(pair.site, "site", "apply", "--once")
    assert applied.returncode == 0, applied.stderr
    assert "applied 1 changes" in applied.stdout
    assert pair.site.ready_messages(DOWNLINK_QUEUE) == 0

    password = unquote(urlsplit(central_account.amqp_url).password or "")
    at_site = Account("warden5", Role.ROBOT, url_for(pair.site.admin_url, "warden5", password))
    warden = pair.site.robot(at_site)  # central's password, the site's broker
    with pair.site.worker(), pair.central.worker():
        event = warden.publish("localisation", {"localised": True})
        wait_for(lambda: pair.central_keys("warden5")[(event.epoch, event.seq)] == 1, what="at central")
    robots = pair.site.with_store(lambda store: store.hazards.robots("warden"))
    assert [(r.name, r.localised) for r in robots] == [("warden5", True)], "in the site's team, as a warden"
    assert [f.site for f in pair.forwards("warden5")] == ["base1"]
