"""Central's missions reach the site through the downlink, the newest version winning; a downlink
message the site cannot parse is kept aside and counted, and the next one still applies."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pika

from fleetbus.api.services.missions import Missions
from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import (
    DOWNLINK_QUEUE,
    DOWNLINK_REJECTED_QUEUE,
    SITES_EXCHANGE,
    site_downlink_queue,
    site_maps_queue,
)
from fleetbus.workers.downlink import apply_downlink
from fleetbus.workers.setup import set_queue_bounds
from fleetbus.workers.site_status import site_view
from fleetbus.workers.sites import mission_change, send_mission_to_sites, send_to_sites
from fleetbus.workers.store import Repositories
from fleetbus.workers.store.missions import Mission
from fleetbus.workers.store.users import User
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_cli import fleetbus
from tests.test_queue_bounds import bounded_by, overflow_counts


def _apply(pair: SitePair) -> int:
    return apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0)


def _at_site(pair: SitePair, mission_id: str) -> Mission | None:
    return pair.site.with_store(lambda repos: repos.missions.get_mission(mission_id))


def test_a_mission_created_at_central_appears_at_the_site_and_the_newest_wins(pair: SitePair) -> None:
    central = pair.central
    now = datetime.now(timezone.utc)
    client = User("client1", UserRole.CLIENT, None, None, None, now, "test", now)

    async def create(repos: Repositories) -> Mission:
        missions = Missions(
            repos.missions, repos.channels, lambda m: send_mission_to_sites(repos.sites, central.admin_url, m)
        )
        return await missions.create(client, "hazard-response", "north tunnel", MissionPlan())

    created = pair.central_store(create)
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1, what="the mission through the downlink")
    assert _apply(pair) == 1
    assert _at_site(pair, created.mission_id) == created, "as central's store has it"

    later = created.updated_at + timedelta(seconds=1)
    closed = pair.central_store(
        lambda repos: repos.missions.transition_mission(
            created.mission_id, MissionState.PLANNING, MissionState.CLOSED, "planner1", later
        )
    )
    # the newer version, then the older one again (a late resend): the newer stays
    send_to_sites(central.admin_url, [pair.name], [mission_change(closed), mission_change(created)])
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 2, what="both versions through the downlink")
    assert _apply(pair) == 2
    assert _at_site(pair, created.mission_id) == closed
    history = pair.site.with_store(lambda repos: repos.missions.mission_history(created.mission_id))
    assert [(h.source, h.target) for h in history] == [
        (None, MissionState.PLANNING),
        (MissionState.PLANNING, MissionState.CLOSED),
    ]
    assert _apply(pair) == 0, "nothing waits"


def test_a_bad_downlink_message_is_kept_aside_and_counted_and_the_next_applies(pair: SitePair) -> None:
    central = pair.central
    now = datetime.now(timezone.utc)
    mission = pair.central_store(
        lambda repos: repos.missions.create_mission("survey", "east shaft", "client1", {}, now)
    )
    connection = pika.BlockingConnection(pika_parameters(central.admin_url))
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        channel.basic_publish(
            SITES_EXCHANGE, f"{pair.name}.mission", b'{"change": "mission", "title": 7}', mandatory=True
        )
    finally:
        connection.close()
    send_to_sites(central.admin_url, [pair.name], [mission_change(mission)])
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 2, what="both through the downlink")

    assert _apply(pair) == 1, "the mission applied after the bad one"
    assert _at_site(pair, mission.mission_id) == mission
    assert pair.site.ready_messages(DOWNLINK_QUEUE) == 0
    assert pair.site.ready_messages(DOWNLINK_REJECTED_QUEUE) == 1, "kept, not lost"
    wait_for(
        lambda: site_view(pair.site.api, pair.site.vhost, []).rejected == 1,
        what="counted where `fleetbus site status` shows it",
    )


def test_a_mission_goes_to_the_site_it_names_only_and_no_map_holds_it_back(pair: SitePair) -> None:
    """A mission naming another site does not come here; one naming this site does. Maps go down
    a queue of their own at central: a map waiting there does not hold a mission back."""
    now = datetime.now(timezone.utc)

    def create(title: str, site: str) -> Mission:
        plan = MissionPlan(site=site).model_dump(mode="json")
        return pair.central_store(
            lambda repos: repos.missions.create_mission("survey", title, "client1", plan, now)
        )

    elsewhere, here = create("west shaft", "base2"), create("east shaft", pair.name)
    pair.stop()  # the shovels stopped: what central sends waits in its queues for the site
    with pair.central.admin_channel() as channel:  # a map on its way down, first
        channel.confirm_delivery()
        channel.basic_publish(SITES_EXCHANGE, f"{pair.name}.map", b"a large map", mandatory=True)
    for mission in (elsewhere, here):
        sent = pair.central_store(
            lambda repos, m=mission: send_mission_to_sites(repos.sites, pair.central.admin_url, m)
        )
        assert sent == ([pair.name] if mission is here else [])
    assert pair.central.ready_messages(site_maps_queue(pair.name)) == 1
    assert pair.central.ready_messages(site_downlink_queue(pair.name)) == 1, "the mission not behind it"
    asyncio.run(pair.start_links())
    wait_for(lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 2, what="both down, by two shovels")
    with pair.site.admin_channel() as channel:
        channel.queue_purge(DOWNLINK_QUEUE)  # the test's map is not one to apply


def test_an_away_sites_full_downlink_drops_its_oldest_counted_and_alerted_on(pair: SitePair) -> None:
    """A site's accounts, removals and missions wait at central within FLEETBUS_SITE_DOWNLINK_MAX; a
    drop there is counted and alerted on (`fleetbus sites sync` sends them again)."""
    central, queue = pair.central, site_downlink_queue(pair.name)
    central.settings = central.settings.updated(site_downlink_max=("2",))
    central.service_accounts()  # `fleetbus setup`: the overflow exchange, where drops are counted
    set_queue_bounds(
        central.settings, replace(central.endpoint, amqp_url=central.admin_url)
    )  # `fleetbus setup`
    wait_for(lambda: bounded_by(central, queue, "fleetbus-site-downlink"), what="the downlink policy")
    pair.stop()  # the site away
    wait_for(lambda: central.api.get_queue(central.vhost, queue).get("consumers") == 0, what="no consumer")
    now = datetime.now(timezone.utc)
    plan = MissionPlan(site=pair.name).model_dump(mode="json")
    missions = [
        pair.central_store(
            lambda repos, n=n: repos.missions.create_mission("survey", f"shaft {n}", "client1", plan, now)
        )
        for n in range(3)
    ]
    send_to_sites(central.admin_url, [pair.name], [mission_change(m) for m in missions])
    with central.worker():
        wait_for(
            lambda: overflow_counts(central).get(f"{queue} maxlen") == 1, what="the oldest dropped, counted"
        )
    assert central.ready_messages(queue) == 2, "the newest two wait"
    shown = fleetbus(central, "alerts", "--json")
    assert shown.returncode == 0, shown.stderr
    [alert] = [a for a in json.loads(shown.stdout)["unacknowledged"] if a["kind"] == "downlink-dropped"]
    assert alert["subject"] == f"site {pair.name}" and f"fleetbus sites sync {pair.name}" in alert["detail"]
