"""Central unreachable: the site serves its team alone, then central gets everything once.

The test cuts the site's link to central for an outage it chooses. Meanwhile an explorer
publishes hazards and a map at the site; the wardens are told at once (not late), fetch the map,
claim and clear through the site, and central receives nothing. Once the link is back, central
holds every event of every robot exactly once, in order, each one sent long enough before the
link came back flagged late, and the site holds each once too.
"""

from __future__ import annotations

import time
from collections import Counter

import pytest

from fleetbus.publishers.rpc import ServiceRefused
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import RobotKind
from tests.factories import hazard, status
from tests.sites.pair import SitePair
from tests.support import assert_stored_once_in_order, site_lane, wait_for
from tests.test_maps import TABLE2, pgm

#: How long the link stays cut: a few seconds in the default suite, ten minutes under ``slow``.
#: What is proven does not depend on the length.
OUTAGES = [
    pytest.param(3.0, id="3s"),
    pytest.param(600.0, id="10min", marks=[pytest.mark.slow, pytest.mark.timeout(1200)]),
]
LATE_AFTER_S = 2.0


def announced(warden, count: int) -> list[Notification]:  # type: ignore[no-untyped-def]
    """The first ``count`` hazard announcements ``warden`` receives (map notes are skipped)."""
    notes: list[Notification] = []
    deadline = time.monotonic() + 30
    while len(notes) < count:
        left = deadline - time.monotonic()
        assert left > 0, f"{warden.robot_id} got {len(notes)} of {count} hazards"
        notes += [n for n in warden.receive(1, timeout=left) if n.hazard_state == "announced"]
    return notes


@pytest.mark.parametrize("outage_s", OUTAGES)
def test_outage_the_site_serves_its_team_then_central_gets_everything_once(
    pair: SitePair, outage_s: float
) -> None:
    pair.central.settings = pair.central.settings.updated(late_after_s=LATE_AFTER_S)
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    wardens = {
        name: pair.site.robot(pair.add_robot(name, RobotKind.WARDEN)) for name in ("warden1", "warden2")
    }
    sent: dict[str, list[tuple[str, int]]] = {name: [] for name in ("explorer1", *wardens)}

    def note(robot: str, events) -> None:  # type: ignore[no-untyped-def]
        sent[robot] += [(event.epoch, event.seq) for event in events]

    with pair.site.worker(), pair.central.worker():
        for name, warden in wardens.items():
            note(name, [warden.publish("localisation", {"localised": True})])
        note("explorer1", [explorer.publish("status", status(90))])
        wait_for(lambda: pair.central.count() == 3, what="the first events at central")

        pair.link.cut()
        cut_at = time.time()
        hazards = explorer.publish_many([("hazard", hazard(i)) for i in range(5)])
        note("explorer1", hazards)
        for warden in wardens.values():
            notes = announced(warden, 5)
            assert [n.hazard_id for n in notes] == [1, 2, 3, 4, 5]
            assert [n.event for n in notes] == hazards
            assert not any(n.late for n in notes), "announced as fast as with central up"
        image = pgm(900, 700)  # two chunks and the map event
        note("explorer1", explorer.publish_map(image, TABLE2))
        assert wait_for(lambda: _fetched(wardens["warden2"], image), what="the map at the site")
        wardens["warden1"].claim_hazard(1)
        with pytest.raises(ServiceRefused):
            wardens["warden2"].claim_hazard(1)
        wardens["warden1"].hazard_reached(1)
        assert wardens["warden1"].hazard_cleared(1)["state"] == "cleared"
        while time.time() < cut_at + outage_s:  # the explorer carries on at 10 Hz
            note("explorer1", [explorer.publish("status", status(80))])
            time.sleep(0.1)
        sentinel = explorer.publish("status", status(70))
        note("explorer1", [sentinel])
        wait_for(
            lambda: pair.site_keys("explorer1")[(sentinel.epoch, sentinel.seq)],
            what="the sentinel at the site",
        )
        assert pair.central.count() == 3, "central received nothing while the link was cut"
        waiting = sum(len(keys) for keys in sent.values()) - 3
        assert pair.uplink_waiting() == waiting, "the site's uplink holds every event since"

        restored_at = time.time()
        pair.link.restore()
        total = sum(len(keys) for keys in sent.values())
        wait_for(lambda: pair.central.count() == total, timeout=120, what=f"central to catch up to {total}")
        wait_for(lambda: len(pair.forwards()) == total, what="every forward recorded")
        wait_for(lambda: pair.uplink_waiting() == 0, what="the uplink empty")

    for robot, keys in sent.items():
        assert_stored_once_in_order(pair.central, robot, keys, site_lane)
        assert pair.site_keys(robot) == Counter(keys), f"{robot}: each event once at the site"
    forwards = {f.key: f for f in pair.forwards()}
    assert {f.site for f in forwards.values()} == {"base1"}
    records = {r.key: r for r in pair.central.find()}
    assert all(r.user_id == r.robot_id for r in records.values()), "each with its robot's validated user"
    for key, record in records.items():
        sent_at = record.sent_at.timestamp()
        if sent_at < cut_at:
            assert not forwards[key].late, f"{key} sent before the cut is not late"
        elif sent_at < restored_at - LATE_AFTER_S - 0.5:
            assert forwards[key].late, f"{key} sent during the outage is late"
    assert pair.central.gaps() == [] and pair.site.gaps() == []


def _fetched(warden, image: bytes) -> bool:  # type: ignore[no-untyped-def]
    try:
        return warden.fetch_map().pgm == image
    except ServiceRefused:  # no map stored yet
        return False
