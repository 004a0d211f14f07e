"""Central's accounts reach the site: a robot registered centrally logs in to its site with the
password central gave it, and works there; removed at central, it is removed at the site, and
central's registry check reports the site's copy until then."""

from __future__ import annotations

import json
from urllib.parse import unquote, urlsplit

from fleetbus.broker.accounts import Account, Role, url_for
from fleetbus.broker.sites import forwarded_robots
from fleetbus.schemas.routing import DOWNLINK_QUEUE, RobotKind
from fleetbus.workers.site_report import report_to_central
from tests.commands import fleetbus as run
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


def _report(pair: SitePair) -> None:
    """The site's report to central, as `fleetbus site apply --name` sends it."""
    team = [robot.name for robot in pair.site.with_store(lambda store: store.hazards.robots())]
    assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url, team)


def test_a_robot_removed_at_central_is_removed_at_its_site(pair: SitePair) -> None:
    pair.central.add("guide5", kind=RobotKind.GUIDE)
    pair.site.accounts.append("guide5")
    assert run(pair.central, "sites", "robots", "base1", "--add", "guide5").returncode == 0
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1, what="the account through the downlink")
    assert run(pair.site, "site", "apply", "--once").returncode == 0
    _report(pair)
    assert run(pair.central, "users", "check").returncode == 0, "the site has its own robot's copy"

    removed = run(pair.central, "users", "remove", "guide5")
    assert removed.returncode == 0, removed.stderr
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1, what="the removal through the downlink")
    _report(pair)  # before the site applied it: it still has the copy
    check = run(pair.central, "users", "check", "--json")
    assert check.returncode == 1, check.stdout
    [drift] = json.loads(check.stdout)["drift"]
    assert (drift["kind"], drift["name"]) == ("site", "base1")
    assert "site base1 keeps the accounts of guide5, which are not its robots" in drift["problem"]

    applied = run(pair.site, "site", "apply", "--once")
    assert applied.returncode == 0 and "applied 1 changes" in applied.stdout, applied.stdout
    assert pair.site.api.get_user("guide5") is None, "it no longer logs in at the site"
    assert "guide5" not in forwarded_robots(pair.site.api, pair.site.vhost)
    assert pair.site.with_store(lambda store: store.hazards.robots()) == []
    _report(pair)
    assert run(pair.central, "users", "check").returncode == 0
