"""A mission changed while central's broker does not answer reaches the sites once it answers
again: the API's sender keeps the newest version of each mission and tries again with backoff."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone
from urllib.parse import urlsplit

from fleetbus.api.services.missions_to_sites import MissionsToSites
from fleetbus.publishers.backoff import Backoff
from fleetbus.schemas.missions import MissionState
from fleetbus.workers.downlink import apply_downlink
from fleetbus.workers.sites import mission_change, send_to_sites
from fleetbus.workers.store.missions import Mission
from tests.link import NetworkLink
from tests.sites.pair import SitePair
from tests.support import wait_for


def test_a_mission_changed_while_centrals_broker_is_away_reaches_the_site_when_it_is_back(
    pair: SitePair,
) -> None:
    central = pair.central
    now = datetime.now(timezone.utc)
    created = pair.central_store(
        lambda repos: repos.missions.create_mission("survey", "east shaft", "client1", {}, now)
    )
    closed = pair.central_store(
        lambda repos: repos.missions.transition_mission(
            created.mission_id,
            MissionState.PLANNING,
            MissionState.CLOSED,
            "planner1",
            now + timedelta(seconds=1),
        )
    )
    link = NetworkLink(urlsplit(central.admin_url).port or 5672).start()
    tries: list[str] = []

    failed: list[str] = []

    async def send(mission: Mission) -> None:
        tries.append(mission.mission_id)
        try:
            await asyncio.to_thread(
                send_to_sites, link.url(central.admin_url), [pair.name], [mission_change(mission)]
            )
        except Exception:
            failed.append(mission.mission_id)
            raise

    async def between_tries(at_least: int) -> None:
        """Until ``at_least`` tries failed and none is under way (the sender waits to try again):
        checked on the sender's own loop, so nothing starts before the caller's next step."""
        deadline = asyncio.get_running_loop().time() + 30
        while not (len(failed) >= at_least and len(tries) == len(failed)):
            assert asyncio.get_running_loop().time() < deadline, f"{len(failed)} tries failed in 30 s"
            await asyncio.sleep(0.01)

    async def scenario() -> int:
        sender = MissionsToSites(send, Backoff(initial=0.1, maximum=0.5, jitter=0.05))
        sender.start()
        try:
            link.cut()
            await sender.changed(created)
            await between_tries(2)
            await sender.changed(closed)  # the newer version replaces the one waiting, before its next try
            assert sender.waiting == 1
            link.restore()
            await asyncio.to_thread(wait_for, lambda: sender.waiting == 0, 30, "the mission sent once back")
            return sender.waiting
        finally:
            await sender.stop()

    try:
        assert asyncio.run(scenario()) == 0
    finally:
        link.stop()
    # the sentinel, a mission of its own: whatever the sender sent is ahead of it on the same way
    # (central's site exchange, the shovel, the site's downlink, applied in order)
    sentinel = pair.central_store(
        lambda repos: repos.missions.create_mission("survey", "sentinel", "client1", {}, now)
    )
    send_to_sites(central.admin_url, [pair.name], [mission_change(sentinel)])
    applied = 0

    def sentinel_applied() -> bool:
        nonlocal applied
        applied += apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0)
        return pair.site.with_store(lambda repos: repos.missions.get_mission(sentinel.mission_id)) is not None

    wait_for(sentinel_applied, what="the sentinel applied at the site")
    assert applied == 2, "the waiting version sent once, the older never, then the sentinel"
    at_site = pair.site.with_store(lambda repos: repos.missions.get_mission(created.mission_id))
    assert at_site == closed
