"""Central's accounts reach the site: a robot registered centrally logs in to its site with the
password central gave it, and works there; removed at central, it is removed at the site (a removal
the site missed, by the next `fleetbus sites sync`, unless the robot is in use there), and central's
registry check reports the site's copy until then. A change made while a sync of the site is under
way is never undone by the sync's older list."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from datetime import datetime, timezone
from unittest import mock
from urllib.parse import unquote, urlsplit

import fleetbus.api.services.accounts as accounts_service
from fleetbus.broker.accounts import Account, Role, url_for
from fleetbus.broker.sites import forwarded_robots
from fleetbus.schemas.routing import DOWNLINK_QUEUE, DOWNLINK_REJECTED_QUEUE, RobotKind
from fleetbus.schemas.site_changes import RobotAccountRemoved
from fleetbus.workers.downlink import apply_downlink
from fleetbus.workers.site_report import report_to_central, team_in_use
from fleetbus.workers.sites import send_to_sites
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

        def site_wardens() -> list[tuple[str, bool]]:
            robots = pair.site.with_store(lambda store: store.hazards.robots("warden"))
            return [(r.name, r.localised) for r in robots]

        # the site's worker takes its copy beside the uplink: central having it says nothing of it
        wait_for(lambda: site_wardens() == [("warden5", True)], what="warden5 in the site's team, localised")
    assert [f.site for f in pair.forwards("warden5")] == ["base1"]


def _report(pair: SitePair) -> None:
    """The site's report to central, as `fleetbus site apply --name` sends it."""
    team, held = pair.site.with_store(lambda store: team_in_use(store.hazards, store.channels))
    assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url, team, held)


def _apply(pair: SitePair, waiting: int) -> int:
    """What `fleetbus site apply --once` does, in this process, once ``waiting`` messages are down."""
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == waiting, what="the changes down the link")
    applied = apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=0.2)
    assert pair.site.ready_messages(DOWNLINK_QUEUE) == 0
    return applied


def _copies(pair: SitePair) -> tuple[object, ...]:
    """The robots' accounts at the site, as they derive from central's: broker accounts (with
    their password hashes and permissions), forwarding, team."""
    api, vhost = pair.site.api, pair.site.vhost
    team = pair.site.with_store(lambda store: store.hazards.robots())
    names = {robot.name for robot in team} | forwarded_robots(api, vhost)
    return (
        sorted((u["name"], u["password_hash"], str(u["tags"])) for u in api.list_users()
               if u["name"] in names),
        sorted(str(p) for p in api.list_permissions(vhost) if p["user"] in names),
        sorted(forwarded_robots(api, vhost)),
        sorted((robot.name, robot.kind) for robot in team),
    )


def _site_status(pair: SitePair) -> dict[str, object]:
    shown = run(pair.site, "site", "status", "--json")
    assert shown.returncode == 0, shown.stderr
    return dict(json.loads(shown.stdout))


def _site_drift(pair: SitePair) -> str:
    check = run(pair.central, "users", "check", "--json")
    assert check.returncode == 1, check.stdout
    [drift] = json.loads(check.stdout)["drift"]
    assert (drift["kind"], drift["name"]) == ("site", "base1")
    return str(drift["problem"])


@contextmanager
def sync_held(pair: SitePair) -> Iterator[None]:
    """`fleetbus sites sync base1` under way: it has read the site's robots, and sends what it read
    once the block is done (the block runs between its read and its send)."""
    read, go = threading.Event(), threading.Event()
    send = accounts_service.send_to_sites

    def held(*args: object) -> None:
        read.set()
        assert go.wait(60), "the test never let the sync go on"
        send(*args)  # type: ignore[arg-type]

    with mock.patch.object(accounts_service, "send_to_sites", held), ThreadPoolExecutor(1) as pool:
        synced = pool.submit(pair.central.with_accounts, lambda accounts: accounts.sync_site("base1"))
        wait_for(lambda: read.is_set() or synced.done(), what="the sync to have read the site's robots")
        try:
            assert read.is_set(), synced.result()
            yield
        finally:
            go.set()
        synced.result(timeout=60)


def test_a_robot_removed_at_central_is_removed_at_its_site(pair: SitePair) -> None:
    pair.site.settings = pair.site.settings.updated(downlink_rejected_max=2)
    asyncio.run(pair.start_links())  # as `fleetbus site up` sets the bound of what it cannot apply
    pair.central.add("guide5", kind=RobotKind.GUIDE)
    pair.central.add("explorer5", kind=RobotKind.EXPLORER)
    pair.site.accounts.extend(["guide5", "explorer5"])
    # added while a sync is under way: the sync read the list before the add and sends it after
    with sync_held(pair):
        assert run(pair.central, "sites", "robots", "base1", "--add", "guide5,explorer5").returncode == 0
    assert _apply(pair, 3) == 3, "both accounts, then the sync's older list"
    assert forwarded_robots(pair.site.api, pair.site.vhost) == {"explorer5", "guide5"}, "the add stays"
    pair.site.add("scout5", kind=RobotKind.EXPLORER)  # the site's own robot: not central's copy
    _report(pair)
    assert run(pair.central, "users", "check").returncode == 0, "the site has its own robots' copies"

    # a sync with nothing changed changes nothing at the site
    before = _copies(pair)
    synced = run(pair.central, "sites", "sync", "base1")
    assert synced.returncode == 0, synced.stderr
    assert "sent base1 the list of its robots: explorer5, guide5" in synced.stdout
    assert _apply(pair, 3) == 3, "both accounts and the list"
    assert _copies(pair) == before
    assert pair.site.ready_messages(DOWNLINK_REJECTED_QUEUE) == 0

    # taken from the site while a sync is under way: the sync read it on the list, and sends its
    # account and the older list after the removal
    with sync_held(pair):
        removed = run(pair.central, "sites", "robots", "base1", "--remove", "guide5")
        assert removed.returncode == 0, removed.stderr
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 4, what="the removal, then the sync's 3")
    _report(pair)  # before the site applied it: it still has the copy
    assert "site base1 keeps the accounts of guide5, which are not its robots" in _site_drift(pair)

    applied = run(pair.site, "site", "apply", "--once")
    assert applied.returncode == 0 and "applied 4 changes" in applied.stdout, applied.stdout
    assert pair.site.api.get_user("guide5") is None, "it no longer logs in at the site"
    assert "guide5" not in forwarded_robots(pair.site.api, pair.site.vhost)
    assert [r.name for r in pair.site.with_store(lambda store: store.hazards.robots())] == [
        "explorer5",
        "scout5",
    ]
    _report(pair)
    assert run(pair.central, "users", "check").returncode == 0

    # a removal the site missed (lost on its way): the next sync removes the copy, but not while
    # the robot is mounted at the site, which refuses and says why
    now = datetime.now(timezone.utc)
    pair.site.with_store(lambda store: store.channels.mount("explorer5", "operator5", "M-5", now))
    assert run(pair.central, "users", "remove", "explorer5").returncode == 0
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1, what="the removal through the downlink")
    with pair.site.admin_channel() as channel:
        channel.queue_purge(DOWNLINK_QUEUE)
    pair.central.with_accounts(lambda accounts: accounts.sync_site("base1"))
    assert _apply(pair, 1) == 0, "the list, refused"
    assert pair.site.api.get_user("explorer5") is not None
    assert pair.site.ready_messages(DOWNLINK_REJECTED_QUEUE) == 1, "kept aside, with the reason"
    _report(pair)
    problem = _site_drift(pair)
    assert "site base1 keeps the accounts of explorer5" in problem
    assert "explorer5 is in use (explorer5 mounted by operator5 for M-5)" in problem

    # each sync while the robot stays mounted is refused again: the site keeps the newest refusals
    # up to its bound (FLEETBUS_DOWNLINK_REJECTED_MAX, set by `site up`) and counts those it dropped
    with pair.site.worker():
        for _ in range(2):
            pair.central.with_accounts(lambda accounts: accounts.sync_site("base1"))
            assert _apply(pair, 1) == 0, "the list, refused again"
        assert pair.site.ready_messages(DOWNLINK_REJECTED_QUEUE) == 2
        wait_for(lambda: _site_status(pair)["rejected_dropped"] == 1, what="the oldest refusal counted")
    # `site status` reads the queue from the management API, which shows it with its next statistics
    wait_for(
        lambda: (s := _site_status(pair))["rejected"] == s["rejected_bound"] == 2, what="2 kept of 2 shown"
    )
    shown = " ".join(run(pair.site, "site", "status").stdout.split())
    assert "downlink messages not applied: 2 " in shown, shown
    dropped = "1 older downlink messages not applied were dropped: fleetbus.downlink.rejected keeps"
    assert f"{dropped} the newest 2 (FLEETBUS_DOWNLINK_REJECTED_MAX)" in shown, shown

    pair.site.with_store(lambda store: store.channels.unmount("explorer5"))
    pair.central.with_accounts(lambda accounts: accounts.sync_site("base1"))
    assert _apply(pair, 1) == 1
    assert pair.site.api.get_user("explorer5") is None
    assert forwarded_robots(pair.site.api, pair.site.vhost) == set()
    assert [r.name for r in pair.site.with_store(lambda store: store.hazards.robots())] == ["scout5"]
    _report(pair)
    assert run(pair.central, "users", "check").returncode == 0
    assert pair.site.api.get_user("scout5") is not None, "central never told the site to remove it"
    # and were central to tell it, the site's own robot is not central's to remove
    send_to_sites(pair.central.admin_url, ["base1"], [RobotAccountRemoved(name="scout5")])
    assert _apply(pair, 1) == 1
    assert pair.site.api.get_user("scout5") is not None, "the site's own robot stays"
