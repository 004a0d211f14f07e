"""A site's events reach central through RabbitMQ's shovel: once, with the robot's validated
user, and recorded as forwarded by the site."""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from dataclasses import dataclass

from fleetbus.broker.uplink import CLASSES, TELEMETRY
from fleetbus.schemas.envelope import Event
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
        # the site's broker routes each event to the uplink and to the site's worker at once: the
        # site's store may still lag when central has them all
        wait_for(lambda: pair.site_keys("explorer1") == Counter(expected), what="each event once at the site")
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


def test_site_up_again_leaves_the_running_links_as_they_are(pair: SitePair) -> None:
    """`fleetbus site up` again (a new bound, say) with the same central: RabbitMQ would restart a
    shovel put again, putting back what it had in flight; the running ones are left running."""
    site = pair.site

    def links_running() -> dict[str, str]:
        """Each link's start (to the second), once every one runs."""
        shovels = site.api.shovel_status(site.vhost)
        if not shovels or any(s["state"] != "running" for s in shovels):
            return {}
        return {s["name"]: s["timestamp"] for s in shovels}

    running = wait_for(links_running, what="every link running")
    second = time.strftime("%H:%M:%S", time.gmtime())
    wait_for(lambda: time.strftime("%H:%M:%S", time.gmtime()) != second, what="the next second")
    site.settings = site.settings.updated(uplink_hazards_max=7)
    asyncio.run(pair.start_links())
    assert links_running() == running, "not one restarted"


def test_the_uplink_classes_drop_telemetry_refuse_hazards_and_the_refused_robot_backs_off(
    pair: SitePair,
) -> None:
    """With the link cut: telemetry beyond its class's bound drops its oldest, counted at the site;
    hazards have a queue of their own, and beyond its bound the site refuses them: the robot then
    tries one event at a time, backing off, instead of sending its backlog again (each resend is
    a duplicate at the site). When the link is back, every hazard reaches central once, and every
    status either reaches it once or is counted as dropped."""
    pair.site.settings = pair.site.settings.updated(uplink_hazards_max=2, uplink_telemetry_max=20)
    asyncio.run(pair.start_links())  # what `fleetbus site up` does again after a change of the bounds
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    with pair.site.worker(), pair.central.worker():
        pair.link.cut()
        telemetry = explorer.publish_many([("status", status(80)) for _ in range(50)])
        hazards = explorer.publish_many([("hazard", hazard(i)) for i in range(2)])
        assert [pair.site.ready_messages(uplink.queue) for uplink in CLASSES] == [2, 0, 20]
        wait_for(lambda: dropped(pair) == 30, what="the 30 oldest status events dropped, counted")
        # the site refuses these; the robot's live events wait behind them while it probes
        refused = explorer.publish_many([("hazard", hazard(i)) for i in range(2, 22)], wait=False)
        later: list[Event] = []
        started = time.monotonic()
        while time.monotonic() - started < 6:
            later.append(explorer.publish("status", status(80), wait=False))
            time.sleep(0.05)
        resends, real = duplicates_at_site(pair), len(refused) + len(later)
        assert resends < real / 10, f"{resends} resends for {real} events published meanwhile"
        assert explorer.outbox.refused() == [], "a nack refuses nothing for good"
        pair.link.restore()
        pair.site.settings = pair.site.settings.updated(uplink_hazards_max=100)
        asyncio.run(pair.start_links())  # room again: the robot's next try finds it
        sent = [*hazards, *refused]
        wait_for(
            lambda: set(pair.central_keys("explorer1")) >= {(e.epoch, e.seq) for e in sent},
            timeout=90,
            what="every hazard at central",
        )
        assert explorer.flush(30)
        statuses = len(telemetry) + len(later)
        # a full telemetry class keeps dropping its oldest while the link catches up
        wait_for(
            lambda: Accounted(statuses, pair.central.count("status"), dropped(pair)),
            timeout=90,
            what="every status at central or counted as dropped at the site",
        )
        assert set(pair.central_keys("explorer1").values()) == {1}, "nothing twice at central"


@dataclass(frozen=True)
class Accounted:
    """The statuses published, those at central and those the site counted as dropped: true when
    each is one or the other (what a timed-out wait shows, when not)."""

    published: int
    at_central: int
    dropped: int

    def __bool__(self) -> bool:
        return self.at_central + self.dropped == self.published


def dropped(pair: SitePair) -> int:
    counts = pair.site.with_store(lambda repos: repos.housekeeping.bound_counts())
    return sum(c.count for c in counts if c.bound == "overflow" and c.subject.startswith(TELEMETRY.queue))


def duplicates_at_site(pair: SitePair) -> int:
    return len(pair.site.with_store(lambda repos: repos.events.duplicates("explorer1")))
