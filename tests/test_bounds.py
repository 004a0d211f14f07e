"""Every bound on what grows holds while the worker runs, against the real broker and both stores:
the event log, the duplicates register, the beacon discards, map versions and staged chunks, the
acknowledged alerts."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.publishers.maps import map_events
from fleetbus.schemas.bodies import MAP_INLINE_BYTES
from fleetbus.schemas.envelope import encode_event
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import load_settings
from fleetbus.workers.store.alerts import NewAlert
from fleetbus.workers.store.repositories import Repositories
from tests.factories import hazard, status
from tests.support import Bus, wait_for
from tests.test_beacon_exchange import publish_raw as publish_beacon
from tests.test_maps import TABLE2, pgm
from tests.test_queue_bounds import fleetbus

QUICK_ROUNDS = 0.2


def counted(bus: Bus) -> dict[tuple[str, str], int]:
    """The bound counts an operator reads (``fleetbus stats``)."""
    return {
        (c.bound, c.subject): c.count for c in bus.with_store(lambda store: store.housekeeping.bound_counts())
    }


def test_the_event_log_duplicates_and_discards_keep_to_their_bounds(stored_bus: Bus) -> None:
    bus = stored_bus
    bus.settings = bus.settings.updated(
        events_keep=("status=3", "*=30d"),
        duplicates_keep="2",
        discards_keep="1",
        prune_every_s=QUICK_ROUNDS,
    )
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    explorer = bus.robot(account)
    long_ago = datetime.now(timezone.utc) - timedelta(days=bus.settings.alerts_keep_days + 1)

    async def old_alerts(store: Repositories) -> list[int]:
        """Two alerts acknowledged long ago: one whose condition ended, one that still holds."""
        new = [NewAlert("robot-stale", f"robot {name}", long_ago, "never heard from") for name in "ab"]
        raised = await store.alerts.raise_alerts(new, long_ago)
        for alert in raised:
            await store.alerts.acknowledge(alert.id, "oper1", long_ago)
        await store.alerts.end_alert(raised[0].id, long_ago)
        return [alert.id for alert in raised]

    ended, still_open = bus.with_store(old_alerts)
    with bus.worker():
        sent = [explorer.publish("status", status(80)) for _ in range(6)]
        for event in sent[:4]:  # the robot sends four again, as after a lost confirm
            bus.publish_raw(
                account, "explorer1.status", encode_event(event), message_id=str(event.message_id)
            )
        for seq in range(3):
            publish_beacon(account.amqp_url, "explorer1.beacon", 900 + seq, None, robot="explorer1")
        wait_for(
            lambda: (
                counted(bus).get(("duplicates", "seen")) == 2
                and counted(bus).get(("discards", "beacon")) == 2
            ),
            what="duplicates and discards pruned to their bounds",
        )
        wait_for(lambda: counted(bus).get(("events", "status")) == 3, what="the oldest statuses pruned")
        wait_for(lambda: counted(bus).get(("alerts", "acknowledged")) == 1, what="the old alert pruned")
    assert bus.with_store(lambda store: store.alerts.get_alert(ended)) is None
    assert bus.with_store(lambda store: store.alerts.get_alert(still_open)) is not None, "open: kept"
    kept = sorted(r.seq for r in bus.find() if r.type == "status")
    assert kept == [e.seq for e in sent[-3:]], "the newest three statuses stay"
    assert len(bus.with_store(lambda store: store.events.duplicates())) == 2
    assert len(bus.with_store(lambda store: store.discards.recent_discards())) == 1


def test_map_versions_keep_the_newest_and_the_fetched_and_unclaimed_chunks_expire(stored_bus: Bus) -> None:
    bus = stored_bus
    bus.settings = bus.settings.updated(map_versions_keep=2, map_staging_ttl="1s", prune_every_s=QUICK_ROUNDS)
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    maps = [pgm(40 + n, 30) for n in range(5)]
    with bus.worker():
        explorer.publish_map(maps[0], TABLE2)
        warden.receive(1, timeout=30)
        assert warden.fetch_map(1).pgm == maps[0]  # a fetch begins: version 1 is referenced
        for image in maps[1:]:
            explorer.publish_map(image, TABLE2)
        warden.receive(4, timeout=30)
        wait_for(lambda: counted(bus).get(("map-versions", "explorer1")) == 2, what="two versions pruned")
        large = map_events(pgm(800, 400), TABLE2)
        assert len(large[0][1]["data"]) > 0 and 800 * 400 > MAP_INLINE_BYTES
        explorer.publish_many(large[:-1])  # chunks whose map event never comes
        wait_for(lambda: counted(bus).get(("map-staging", "chunks")) == len(large) - 1, what="chunks expired")
        explorer.publish_many(large[-1:])  # too late: its chunks are gone
        wait_for(lambda: bus.ready_messages("fleetbus.dead-letters") == 1, what="the late map refused")
        assert warden.fetch_map().pgm == maps[-1]
    versions = bus.with_store(lambda store: store.maps.map_versions())
    assert [v.version for v in versions] == [5, 4, 1], "the newest two, and the one being fetched"
    listed = fleetbus(bus, "map", "list")
    assert listed.returncode == 0, listed.stderr
    rows = [line.split() for line in listed.stdout.splitlines() if "explorer1 #" in line]
    assert [row[1] for row in rows] == ["5", "4", "1"]
    pruned = fleetbus(bus, "map", "export", "--version", "2", "--out", str(bus.settings.data_dir / "map"))
    assert pruned.returncode == 1 and "map version 2 was pruned" in pruned.stderr


def test_an_open_hazard_and_its_event_stay_and_go_once_it_is_cleared(stored_bus: Bus) -> None:
    bus = stored_bus
    bus.settings = bus.settings.updated(
        events_keep=("hazard=1s",), hazards_keep="1s", prune_every_s=QUICK_ROUNDS
    )
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True, "pose": {"x": 0.0, "y": 0.0}})
        open_one = explorer.publish("hazard", hazard(1))
        explorer.publish("hazard", hazard(2))
        notes = warden.receive(2, timeout=30)
        for method in ("hazard.claim", "hazard.reached", "hazard.cleared"):
            warden.call(method, hazard_id=notes[1].hazard_id)
        # the cleared one, the later of the two, goes once it is a second old: so is the open one
        wait_for(lambda: bus.count("hazard") == 1, what="the cleared hazard's event pruned")
        # and the registry's cleared hazard (this broker has no hazard uplink: it is no site)
        wait_for(lambda: counted(bus).get(("hazards", "cleared")) == 1, what="the cleared hazard pruned")
    [left] = [record for record in bus.find() if record.type == "hazard"]
    assert left.seq == open_one.seq, "the open hazard's event stays, however old"
    [registered] = bus.with_store(lambda store: store.hazards.recent_hazards(10))
    assert (registered.hazard_id, registered.state.value) == (notes[0].hazard_id, "announced")
    assert bus.count("localisation") == 1, "a type without a bound is kept"


@pytest.mark.parametrize(
    ("variable", "value", "says"),
    [
        ("FLEETBUS_EVENTS_KEEP", "status=1GB", "not a size"),
        ("FLEETBUS_EVENTS_KEEP", "status", "TYPE=LIMIT"),
        ("FLEETBUS_DUPLICATES_KEEP", "soon", "an age"),
        ("FLEETBUS_HAZARDS_KEEP", "1GB", "not a size"),
        ("FLEETBUS_HAZARDS_KEEP", "0", "above 0"),
        ("FLEETBUS_LEDGER_KEEP", "0d", "above 0"),
        ("FLEETBUS_EVENTS_KEEP", "status=0", "above 0"),
        ("FLEETBUS_INBOX_MAX", "7d", "not '7d'"),
        ("FLEETBUS_MAP_STAGING_TTL", "500", "an age"),
        ("FLEETBUS_MAP_VERSIONS_KEEP", "0", "positive"),
        ("FLEETBUS_FIELD_INDEXES_MAX", "60", "MongoDB allows 64"),
    ],
)
def test_a_bound_that_does_not_parse_stops_at_start_naming_its_variable(
    variable: str, value: str, says: str
) -> None:
    with pytest.raises(ValueError, match=variable) as refused:
        load_settings({variable: value})
    assert says in str(refused.value)
