"""A site's events reach central through RabbitMQ's shovel: once, with the robot's validated
user, and recorded as forwarded by the site."""

from __future__ import annotations

import asyncio
from collections import Counter

from fleetbus.schemas.routing import RobotKind
from tests.factories import hazard, status
from tests.sites.pair import SitePair
from tests.support import wait_for


def test_link_up_events_reach_central_once_with_their_site_and_user(pair: SitePair) -> None:
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with pair.site.worker(), pair.central.worker():
        items = [("hazard", hazard(i)) if i % 3 == 0 else ("status", status(80)) for i in range(30)]
        items.append(("beacon", {"beacon_id": "b1", "rssi": -60, "pose": {"x": 1.0, "y": 2.0}}))
        sent = explorer.publish_many(items)
        expected = {(event.epoch, event.seq) for event in sent}
        wait_for(lambda: set(pair.central_keys("explorer1")) == expected, what="every event at central")
        wait_for(lambda: len(pair.forwards("explorer1")) == len(sent), what="every forward recorded")
    assert set(pair.central_keys("explorer1").values()) == {1}, "each event once at central"
    assert set(pair.site_keys("explorer1").values()) == {1} and set(pair.site_keys("explorer1")) == expected
    records = pair.central.find()
    assert {(r.user_id, r.exchange) for r in records} == {
        ("explorer1", "explorer1.events"),
        ("explorer1", "explorer1.beacon"),  # through central's beacon check too
    }
    forwards = pair.forwards("explorer1")
    assert {f.site for f in forwards} == {"base1"} and not any(f.late for f in forwards)
    assert pair.uplink_waiting() == 0


def test_a_full_uplink_refuses_new_events_which_wait_in_the_robots_outbox(pair: SitePair) -> None:
    pair.site.settings = pair.site.settings.updated(uplink_max=5)
    asyncio.run(pair.start_links())  # what `fleetbus site up` does again after a change of the bound
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with pair.site.worker(), pair.central.worker():
        pair.link.cut()
        sent = explorer.publish_many([("status", status(80)) for _ in range(8)], wait=False)
        wait_for(lambda: pair.uplink_waiting() == 5, what="the uplink full")
        wait_for(lambda: explorer.outbox.pending() == 3, what="the refused three kept in the outbox")
        assert pair.uplink_waiting() == 5
        pair.link.restore()
        expected = Counter((event.epoch, event.seq) for event in sent)
        wait_for(lambda: pair.central_keys("explorer1") == expected, timeout=60, what="all 8 at central")
        assert explorer.flush(30)
    assert pair.site_keys("explorer1") == expected, (
        "the resent three recognised at the site, not stored twice"
    )
