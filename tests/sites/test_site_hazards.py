"""A site's hazard states reach central: claimed, reached and cleared at the site while central is
away, central shows the hazard cleared by the site's warden once the link is back; an older or
repeated state never undoes a newer one; a site sets no state of a hazard that is not its own."""

from __future__ import annotations

import asyncio
import json
import time
from datetime import timedelta
from typing import Any

import pika
import pika.exceptions
import pytest

from fleetbus.broker.sites import add_site_account
from fleetbus.publishers.rpc import ServiceRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, new_epoch
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import HAZARD_UPLINK_QUEUE, RobotKind, site_hazards_exchange
from fleetbus.schemas.site_hazards import SITE_HAZARD_TYPE, SiteHazardState
from fleetbus.workers.site_hazards import MALFORMED, NOT_THE_SITES_HAZARD, NOT_THE_SITES_ROBOT
from fleetbus.workers.sites import assign_robots
from fleetbus.workers.store.hazards import Hazard, HazardState
from tests.console.support import http_session, running_console
from tests.factories import hazard
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_cli import fleetbus


def announced(warden: Any, timeout: float = 30.0) -> Notification:
    """The next hazard announcement ``warden`` receives (map notes are skipped)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"{warden.robot_id} got no hazard"
        notes = [n for n in warden.receive(1, timeout=left) if n.hazard_state == "announced"]
        if notes:
            return notes[0]


def central_hazards(pair: SitePair, robot: str) -> list[Hazard]:
    found = pair.central_store(lambda repos: repos.hazards.recent_hazards(100))
    return [h for h in found if h.robot_id == robot]


def site_hazard(pair: SitePair, hazard_id: int) -> Hazard:
    found = pair.site.with_store(lambda repos: repos.hazards.get_hazard("default", hazard_id))
    assert found is not None
    return found


def test_states_made_at_the_site_while_central_is_away_reach_central(pair: SitePair) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    warden = pair.site.robot(pair.add_robot("warden1", RobotKind.WARDEN))
    with pair.site.worker(), pair.central.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: pair.central.count() == 1, what="the link up")

        pair.link.cut()
        event = explorer.publish("hazard", hazard(0))
        note = announced(warden)
        assert note.event == event
        warden.claim_hazard(note.hazard_id)
        warden.hazard_reached(note.hazard_id)
        warden.hazard_cleared(note.hazard_id)
        cleared = site_hazard(pair, note.hazard_id)
        assert cleared.state is HazardState.CLEARED
        # every version is on its way: in the site's queue until the link is back
        wait_for(
            lambda: not pair.site.with_store(lambda repos: repos.hazards.unsent_hazards(10)),
            what="the site's hazard states queued for central",
        )
        assert pair.site.ready_messages(HAZARD_UPLINK_QUEUE) >= 1
        assert central_hazards(pair, "explorer1") == [], "central has heard nothing yet"

        pair.link.restore()
        [shown] = wait_for(
            lambda: [h for h in central_hazards(pair, "explorer1") if h.state is HazardState.CLEARED],
            what="the hazard cleared at central",
        )
        assert (shown.site, shown.site_hazard_id, shown.claimed_by) == ("base1", note.hazard_id, "warden1")
        assert (shown.epoch, shown.seq, shown.event) == (event.epoch, event.seq, cleared.event)
        assert (shown.announced_at, shown.claimed_at, shown.reached_at, shown.cleared_at) == (
            cleared.announced_at,
            cleared.claimed_at,
            cleared.reached_at,
            cleared.cleared_at,
        )
        assert shown.version == cleared.version
        wait_for(lambda: pair.central.count("hazard", "explorer1") == 1, what="the hazard event at central")
        # stored before the lane's services run; recorded as forwarded after its hazard gate had it
        wait_for(lambda: len(pair.forwards("explorer1")) == 1, what="the hazard event recorded as forwarded")
        assert len(central_hazards(pair, "explorer1")) == 1, "the event registers no second hazard"
        wait_for(lambda: pair.site.ready_messages(HAZARD_UPLINK_QUEUE) == 0, what="the queue drained")


def _state(robot: str, version: int, state: str = "announced", **fields: Any) -> SiteHazardState:
    event = build_event("hazard", robot, new_epoch(), 3, hazard(0))
    given: dict[str, Any] = {"hazard_id": 7, "announced_at": event.sent_at, **fields}
    return SiteHazardState(
        mission_id="default",
        robot_id=robot,
        epoch=event.epoch,
        seq=event.seq,
        event=event.model_dump(mode="json"),
        state=state,  # type: ignore[arg-type]
        received_at=event.sent_at,
        version=version,
        **given,
    )


def send_as_site(pair: SitePair, bodies: list[bytes], site: str | None = None) -> None:
    """Publish ``bodies`` to ``site``'s hazards exchange at central as the site (confirmed)."""
    assert pair.account is not None
    connection = blocking_connection(pair.account.amqp_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for body in bodies:
            channel.basic_publish(
                site_hazards_exchange(site or pair.name),
                "",
                body,
                pika.BasicProperties(delivery_mode=2, content_type="application/json", type=SITE_HAZARD_TYPE),
                mandatory=True,
            )
    finally:
        if connection.is_open:
            connection.close()


def test_an_older_or_repeated_state_never_undoes_a_newer_one(pair: SitePair) -> None:
    pair.add_robot("explorer1", RobotKind.EXPLORER)
    announced_ = _state("explorer1", 1)
    at = announced_.received_at
    claimed = announced_.model_copy(
        update={
            "state": "claimed",
            "claimed_by": "warden1",
            "claimed_at": at + timedelta(seconds=1),
            "version": 2,
        }
    )
    cleared = claimed.model_copy(
        update={
            "state": "cleared",
            "reached_at": at + timedelta(seconds=2),
            "cleared_at": at + timedelta(seconds=3),
            "version": 4,
        }
    )
    with pair.central.worker() as worker:
        send_as_site(pair, [m.model_dump_json().encode() for m in (cleared, claimed, cleared, announced_)])
        assert worker.context is not None
        counts = worker.context.site_hazards.counts
        wait_for(lambda: counts["applied"] + counts["stale"] == 4, what="four states taken")
    [shown] = central_hazards(pair, "explorer1")
    assert (shown.state, shown.claimed_by, shown.version, shown.site) == (
        HazardState.CLEARED,
        "warden1",
        4,
        "base1",
    )
    assert (shown.reached_at, shown.cleared_at) == (cleared.reached_at, cleared.cleared_at)


def test_a_site_sets_no_state_of_a_hazard_not_its_own(pair: SitePair) -> None:
    pair.add_robot("explorer1", RobotKind.EXPLORER)
    pair.central.add("explorer9", kind=RobotKind.EXPLORER)  # a robot of central's, at no site
    pair.central.add("explorer8", kind=RobotKind.EXPLORER)  # a robot of another site
    asyncio.run(add_site_account(pair.central.admin_url, pair.central.api, "base2", rotate=True))
    pair.central.accounts.append("base2")
    central = pair.central
    pair.central_store(
        lambda repos: assign_robots(
            repos.sites, repos.hazards, central.api, central.admin_url, "base2", ["explorer8"]
        )
    )
    # another site's exchange: refused by central's broker
    with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
        send_as_site(pair, [_state("explorer8", 1).model_dump_json().encode()], site="base2")
    assert refused.value.reply_code == 403

    # a hazard central registered as its own, for a robot that is the site's now
    own = _state("explorer1", 1)
    central.with_store(
        lambda repos: repos.hazards.add_hazard(
            "default", own.robot_id, own.epoch, own.seq, own.event, own.received_at, held=False
        )
    )
    taken_over = own.model_copy(update={"state": "cleared", "version": 9, "cleared_at": own.received_at})
    bodies = [
        _state("explorer9", 1).model_dump_json().encode(),
        _state("explorer8", 1).model_dump_json().encode(),
        taken_over.model_dump_json().encode(),
        b'{"not": "a hazard state"}',
        _state("explorer1", 1).model_dump_json().encode(),  # its own: applied, the worker goes on
    ]
    with central.worker() as worker:
        send_as_site(pair, bodies)
        assert worker.context is not None
        counts = worker.context.site_hazards.counts
        wait_for(lambda: sum(counts.values()) == 5, what="five states taken")
        assert counts == {NOT_THE_SITES_ROBOT: 2, NOT_THE_SITES_HAZARD: 1, MALFORMED: 1, "applied": 1}
        letters = wait_for(lambda: len(ls := central.dead_letters()) == 4 and ls, what="four dead letters")

        def reported() -> dict[str, int]:  # the worker's status, as `fleetbus stats` reads it
            statuses = central.with_store(lambda repos: repos.statuses.statuses())
            return {k: v for status in statuses for k, v in status.counters.items() if k.startswith("site_")}

        wait_for(
            lambda: reported().get(f"site_hazards.{NOT_THE_SITES_ROBOT}") == 2, what="the refusals counted"
        )
    assert sorted(letter.reason for letter in letters) == sorted(
        [NOT_THE_SITES_ROBOT, NOT_THE_SITES_ROBOT, NOT_THE_SITES_HAZARD, MALFORMED]
    )
    assert central_hazards(pair, "explorer9") == [] and central_hazards(pair, "explorer8") == []
    mine = central_hazards(pair, "explorer1")
    assert {(h.site, h.state) for h in mine} == {
        (None, HazardState.ANNOUNCED),
        ("base1", HazardState.ANNOUNCED),
    }


def test_central_shows_a_sites_hazard_and_takes_no_step_of_it(pair: SitePair) -> None:
    pair.add_robot("explorer1", RobotKind.EXPLORER)
    warden = pair.central.robot(pair.central.add("warden9", kind=RobotKind.WARDEN))  # central's own
    claimed = _state("explorer1", 2, "claimed", claimed_by="warden1", hazard_id=5)
    held = _state("explorer1", 0, "held", hazard_id=6, announced_at=None, held_reason="no warden took it")
    with pair.central.worker() as worker:
        send_as_site(pair, [claimed.model_dump_json().encode(), held.model_dump_json().encode()])
        assert worker.context is not None
        counts = worker.context.site_hazards.counts
        wait_for(lambda: counts["applied"] == 2, what="the states applied")
        shown = {h.site_hazard_id: h for h in central_hazards(pair, "explorer1")}
        with pytest.raises(ServiceRefused, match="site base1"):
            warden.claim_hazard(shown[6].hazard_id)
        assert warden.open_hazards() == [], "central's wardens are not given a site's hazards"

    listed = fleetbus(pair.central, "hazards", "--json")
    assert listed.returncode == 0, listed.stderr
    rows = {row["site_hazard_id"]: row for row in map(json.loads, listed.stdout.splitlines())}
    assert (rows[5]["site"], rows[5]["state"], rows[5]["claimed_by"]) == ("base1", "claimed", "warden1")
    assert rows[6]["held_because"] == "held at site base1: no warden took it"

    with (
        running_console(pair.central) as console,
        http_session(console, console.user("oper1", UserRole.OPERATOR)) as http,
    ):
        page = http.get("/console/hazards")
        assert page.status_code == 200
        card = page.text[page.text.index(f'id="hazard-default-{shown[5].hazard_id}"') :]
        card = card[: card.index("</article>")]
        assert "site base1 (#5 there)" in card and "warden1" in card
        assert "hx-post" not in card, "no step for central to take"


def test_a_full_hazard_uplink_keeps_the_states_unsent_at_the_site_until_there_is_room(pair: SitePair) -> None:
    pair.site.settings = pair.site.settings.updated(uplink_max=1)
    asyncio.run(pair.start_links())  # what `fleetbus site up` does again after a change of the bound
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    warden = pair.site.robot(pair.add_robot("warden1", RobotKind.WARDEN))
    with pair.site.worker(), pair.central.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: pair.central.count() == 1, what="the link up")
        pair.link.cut()
        events = [
            explorer.publish("hazard", hazard(i), wait=False) for i in range(3)
        ]  # the full uplink refuses two
        for _ in events:
            announced(warden)
        wait_for(lambda: pair.site.ready_messages(HAZARD_UPLINK_QUEUE) == 1, what="the hazard uplink full")
        # the queue shows the first before the uplink marks it sent: wait for the mark
        wait_for(
            lambda: len(pair.site.with_store(lambda repos: repos.hazards.unsent_hazards(10))) == 2,
            what="the two refused states waiting in the site's store, not dropped",
        )
        pair.link.restore()
        wait_for(
            lambda: (
                sorted((h.seq, h.state) for h in central_hazards(pair, "explorer1"))
                == [(e.seq, HazardState.ANNOUNCED) for e in events]
            ),
            timeout=60,
            what="all three announced at central",
        )
