"""The team's newest map reaches the site: a map a robot at central made is fetched by a robot of
the site from its own site; the site's own maps are not sent back to it."""

from __future__ import annotations

import hashlib
import logging
from dataclasses import replace
from datetime import datetime, timezone

import pytest

from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.routing import DOWNLINK_QUEUE, DOWNLINK_REJECTED_QUEUE, RobotKind, site_maps_queue
from fleetbus.schemas.site_changes import MapChange, MapChunk
from fleetbus.workers.downlink import apply_downlink
from fleetbus.workers.setup import set_queue_bounds
from fleetbus.workers.sites import send_to_sites
from tests.sites.pair import SitePair
from tests.support import Bus, wait_for
from tests.test_maps import TABLE2, pgm
from tests.test_queue_bounds import bounded_by, overflow_counts


def test_a_map_stored_at_central_is_fetched_by_a_site_robot_from_the_site(pair: SitePair) -> None:
    explorer = pair.central.robot(pair.central.add("explorer9", kind=RobotKind.EXPLORER))
    site_warden = pair.site.robot(pair.add_robot("warden3", RobotKind.WARDEN))
    image = pgm(300, 200)
    with pair.central.worker():
        explorer.publish_map(image, TABLE2)
        wait_for(
            lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1,
            timeout=60,
            what="the map through the downlink",
        )
    assert apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0) == 1
    with pair.site.worker():
        fetched = site_warden.fetch_map()
    assert fetched.pgm == image and fetched.robot_id == "explorer9"
    assert {k: fetched.metadata[k] for k in TABLE2} == TABLE2

    versions = pair.site.with_store(lambda repos: repos.maps.map_versions())
    assert [v.robot_id for v in versions] == ["explorer9"]


def test_a_map_larger_than_a_chunk_goes_down_in_chunks_and_is_fetched_whole(pair: SitePair) -> None:
    explorer = pair.central.robot(pair.central.add("explorer9", kind=RobotKind.EXPLORER))
    site_warden = pair.site.robot(pair.add_robot("warden3", RobotKind.WARDEN))
    image = pgm(1500, 1000)  # 1.5 MB: three chunks
    parts = -(-len(image) // MAP_CHUNK_BYTES)
    assert parts == 3
    with pair.central.worker():
        explorer.publish_map(image, TABLE2)
        wait_for(
            lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == parts + 1,
            timeout=60,
            what="the chunks and the map change through the downlink",
        )
    assert apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0) == parts + 1
    with pair.site.worker():
        fetched = site_warden.fetch_map()
    assert fetched.pgm == image and fetched.robot_id == "explorer9"
    [version] = pair.site.with_store(lambda repos: repos.maps.map_versions())
    map_id = f"downlink:explorer9:{version.epoch}:{version.seq}"
    assert pair.site.with_store(lambda repos: repos.maps.staged_map_chunks(map_id)) == {}, "chunks dropped"


def test_a_chunked_map_with_a_chunk_missing_is_kept_aside_and_nothing_is_stored(pair: SitePair) -> None:
    image = pgm(1500, 1000)
    change = MapChange(
        robot_id="explorer9",
        epoch="e1",
        seq=7,
        metadata=TABLE2,
        created_at=datetime.now(timezone.utc),
        sha256=hashlib.sha256(image).hexdigest(),
        map_id="downlink:explorer9:e1:7",
        chunks=3,
    )
    first = MapChunk(map_id="downlink:explorer9:e1:7", index=0, data=image[:MAP_CHUNK_BYTES])
    send_to_sites(pair.central.admin_url, [pair.name], [first, change])
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 2, what="both through the downlink")

    assert apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0) == 1, (
        "the chunk"
    )
    assert pair.site.ready_messages(DOWNLINK_REJECTED_QUEUE) == 1, "the change kept, not lost"
    assert pair.site.with_store(lambda repos: repos.maps.map_versions()) == []


def test_a_map_no_queue_takes_for_a_site_is_said_and_the_map_is_still_announced(
    pair: SitePair, caplog: pytest.LogCaptureFixture
) -> None:
    """Central's maps queue for the site gone (deleted by hand, a broker restored without it): the
    broker returns the map; the worker says which site missed it and how to make the queue again,
    and central's own wardens still get the map."""
    explorer = pair.central.robot(pair.central.add("explorer9", kind=RobotKind.EXPLORER))
    warden = pair.central.robot(pair.central.add("warden9", kind=RobotKind.WARDEN))
    pair.central.api.delete_queue(pair.central.vhost, site_maps_queue(pair.name))
    with pair.central.worker(), caplog.at_level(logging.ERROR, logger="fleetbus.sites"):
        sentinel = explorer.publish_map(pgm(30, 20), TABLE2)[-1]
        [note] = warden.receive(1, timeout=30)
        assert note.event == sentinel and note.map_version == 1
    said = [r.getMessage() for r in caplog.records if "not sent to site" in r.getMessage()]
    assert said == [
        f"map 1 of explorer9 not sent to site {pair.name}: central's broker has no maps queue "
        "bound for it (`fleetbus sites sync` makes it)"
    ]


def held_maps(bus: Bus, queue: str) -> list[MapChange]:
    """What ``queue`` holds, oldest first (taken, not acked: it stays)."""
    with bus.admin_channel() as channel:
        held = []
        while (got := channel.basic_get(queue))[0] is not None:
            held.append(MapChange.model_validate_json(got[2]))
        return held


def test_an_away_sites_maps_queue_keeps_the_newest_and_counts_the_dropped(pair: SitePair) -> None:
    """A site away needs only the newest map: its queue at central keeps FLEETBUS_SITE_MAPS_MAX."""
    central, maps = pair.central, site_maps_queue(pair.name)
    central.settings = central.settings.updated(site_maps_max=("2",))
    set_queue_bounds(
        central.settings, replace(central.endpoint, amqp_url=central.admin_url)
    )  # `fleetbus setup`
    wait_for(lambda: bounded_by(central, maps, "fleetbus-site-maps"), what="the maps policy")
    pair.stop()  # the site away: its shovels no longer take its maps
    wait_for(lambda: central.api.get_queue(central.vhost, maps).get("consumers") == 0, what="no consumer")
    explorer = central.robot(central.add("explorer9", kind=RobotKind.EXPLORER))
    with central.worker():
        sent = [explorer.publish_map(pgm(30 + n, 20), TABLE2) for n in range(4)]
        wait_for(
            lambda: overflow_counts(central).get(f"{maps} maxlen") == 2, what="two maps dropped, counted"
        )
    assert [change.seq for change in held_maps(central, maps)] == [events[-1].seq for events in sent[2:]]
