"""Hazard states between a site and central on every adapter: each change is a new version the
site sends once; central takes a site's hazard newest-wins, and never one that is not the site's."""

from __future__ import annotations

import dataclasses
from datetime import timedelta

import pytest

from fleetbus.workers.store.hazards import Hazard, HazardRefused, HazardState, SiteApplied
from fleetbus.workers.store.repositories import Repositories
from tests.store.test_coordination_contract import BODY, EPOCH, T0


async def _claimed_at_site(store: Repositories) -> list[Hazard]:
    """A hazard's versions at a site as it is announced, claimed, reached and cleared."""
    hazards = store.hazards
    versions = [await hazards.add_hazard("m1", "explorer1", EPOCH, 7, BODY, T0, held=True)]
    await hazards.mark_announced(versions[-1:], T0 + timedelta(seconds=1))
    versions.append(await _get(store, 1))
    versions.append(await hazards.claim("m1", 1, "warden1", T0 + timedelta(seconds=2)))
    versions.append(await hazards.mark_reached("m1", 1, "warden1", T0 + timedelta(seconds=3)))
    versions.append(await hazards.mark_cleared("m1", 1, "warden1", T0 + timedelta(seconds=4)))
    return versions


async def _get(store: Repositories, hazard_id: int, mission: str = "m1") -> Hazard:
    hazard = await store.hazards.get_hazard(mission, hazard_id)
    assert hazard is not None
    return hazard


async def test_each_change_is_a_new_version_sent_once(store: Repositories) -> None:
    hazards = store.hazards
    held = await hazards.add_hazard("m1", "explorer1", EPOCH, 7, BODY, T0, held=True)
    assert held.version == 0 and held.site is None
    assert await hazards.unsent_hazards(10) == [held]
    await hazards.mark_sent([held])
    assert await hazards.unsent_hazards(10) == []

    await hazards.mark_announced([held], T0)
    announced = await _get(store, 1)
    claimed = await hazards.claim("m1", 1, "warden1", T0 + timedelta(seconds=1))
    assert held.version < announced.version < claimed.version
    assert await hazards.unsent_hazards(10) == [claimed]
    await hazards.mark_sent([announced])  # an older version sent: the newest still waits
    assert await hazards.unsent_hazards(10) == [claimed]
    await hazards.mark_sent([claimed])
    await hazards.mark_sent([announced])  # late news of an older one marks nothing back
    assert await hazards.unsent_hazards(10) == []

    released = await hazards.release("m1", 1, "warden1", T0 + timedelta(seconds=2))
    assert released.state is HazardState.ANNOUNCED and released.version > claimed.version
    assert await hazards.unsent_hazards(10) == [released]


async def test_unsent_hazards_come_in_order_and_bounded(store: Repositories) -> None:
    for seq in range(5):
        await store.hazards.add_hazard("m1", "explorer1", EPOCH, seq, BODY, T0, held=True)
    first = await store.hazards.unsent_hazards(3)
    assert [h.hazard_id for h in first] == [1, 2, 3]
    await store.hazards.mark_sent(first)
    assert [h.hazard_id for h in await store.hazards.unsent_hazards(3)] == [4, 5]


async def test_central_takes_a_sites_hazard_newest_wins(store: Repositories) -> None:
    site_versions = await _claimed_at_site(store)  # played here: as if at the site, for another robot
    at_site = [
        dataclasses.replace(v, robot_id="explorer2", mission_id="m2", hazard_id=v.hazard_id + 40)
        for v in site_versions
    ]
    central = store.hazards
    own = await central.add_hazard("m2", "explorer9", EPOCH, 1, BODY, T0, held=True)  # central's own first

    done, shown = await central.apply_site_hazard("base1", at_site[2])  # claimed, before anything else
    assert done is SiteApplied.APPLIED and shown is not None
    assert (shown.mission_id, shown.hazard_id, shown.site, shown.site_hazard_id) == ("m2", 2, "base1", 41)
    assert (shown.state, shown.claimed_by, shown.claimed_at) == (
        HazardState.CLAIMED,
        "warden1",
        at_site[2].claimed_at,
    )
    assert shown.event == BODY and shown.received_at == T0 and shown.version == at_site[2].version

    for older in (at_site[0], at_site[1], at_site[2]):  # repeated, or overtaken: nothing goes back
        done, kept = await central.apply_site_hazard("base1", older)
        assert done is SiteApplied.STALE and kept == shown

    done, cleared = await central.apply_site_hazard("base1", at_site[4])
    assert done is SiteApplied.APPLIED and cleared is not None
    assert (cleared.state, cleared.claimed_by, cleared.hazard_id) == (HazardState.CLEARED, "warden1", 2)
    assert cleared.reached_at == at_site[3].reached_at and cleared.cleared_at == at_site[4].cleared_at
    done, _ = await central.apply_site_hazard("base1", at_site[3])
    assert done is SiteApplied.STALE
    assert await _get(store, 2, "m2") == cleared
    assert await _get(store, 1, "m2") == own, "central's own hazard untouched"


async def test_a_sites_hazard_is_neither_announced_nor_sent_by_central(store: Repositories) -> None:
    held = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 7, BODY, T0, held=True)
    site_held = dataclasses.replace(held, robot_id="explorer2", event={**BODY, "n": 2})
    await store.hazards.mark_sent([held])
    done, shown = await store.hazards.apply_site_hazard("base1", site_held)
    assert done is SiteApplied.APPLIED and shown is not None and shown.state is HazardState.HELD
    assert [h.hazard_id for h in await store.hazards.unannounced_hazards()] == [1], "its site announces it"
    assert [h.hazard_id for h in (await store.hazards.hold_hazards(())).hazards] == [1]
    assert await store.hazards.unsent_hazards(10) == []
    assert {h.hazard_id for h in await store.hazards.open_hazards("m1")} == {1, 2}, "central shows it"


async def test_a_site_cannot_set_a_hazard_that_is_not_its_own(store: Repositories) -> None:
    own = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 7, BODY, T0, held=True)
    newer = dataclasses.replace(own, state=HazardState.CLEARED, version=99, cleared_at=T0)
    done, shown = await store.hazards.apply_site_hazard("base1", newer)
    assert done is SiteApplied.NOT_THE_SITES and shown == own
    assert await _get(store, 1) == own

    other = dataclasses.replace(own, seq=8, version=1)
    assert (await store.hazards.apply_site_hazard("base2", other))[0] is SiteApplied.APPLIED
    done, _ = await store.hazards.apply_site_hazard("base1", dataclasses.replace(other, version=5))
    assert done is SiteApplied.NOT_THE_SITES
    assert (await _get(store, 2)).site == "base2" and (await _get(store, 2)).version == 1


async def test_a_sites_hazard_takes_no_step_at_central(store: Repositories) -> None:
    announced = await store.hazards.add_hazard("m1", "explorer1", EPOCH, 7, BODY, T0, held=False)
    done, shown = await store.hazards.apply_site_hazard("base1", dataclasses.replace(announced, seq=8))
    assert done is SiteApplied.APPLIED and shown is not None and shown.state is HazardState.ANNOUNCED
    with pytest.raises(HazardRefused, match="site base1"):
        await store.hazards.claim("m1", shown.hazard_id, "warden9", T0)
    assert await _get(store, shown.hazard_id) == shown
