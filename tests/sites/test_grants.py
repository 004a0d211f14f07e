"""Granting a site's account at central the robots of its list, as the list changes meanwhile."""

from __future__ import annotations

import asyncio
from typing import cast

import pytest

from fleetbus.broker.sites import add_site_account, site_permissions
from fleetbus.workers.sites import CHANGE_ATTEMPTS, grant_listed
from fleetbus.workers.store import Repositories
from fleetbus.workers.store.sites import SiteList, SiteRegistry, StaleRevision
from tests.support import Bus

SITE = "base1"


class ChangedAfterEveryRead:
    """The registry as another administrator keeps changing it: each read of a site's list is
    followed by a change of it (explorer1 and explorer2 in turn)."""

    def __init__(self, sites: SiteRegistry) -> None:
        self._sites = sites
        self.reads = 0

    async def robots_of(self, site: str) -> SiteList | None:
        listed = await self._sites.robots_of(site)
        self.reads += 1
        await self._sites.set_robots(site, [f"explorer{1 + self.reads % 2}"])
        return listed


def test_a_list_changed_after_every_read_is_granted_a_bounded_number_of_times(bus: Bus) -> None:
    asyncio.run(add_site_account(bus.admin_url, bus.api, SITE, rotate=True))
    bus.accounts.append(SITE)

    async def churned(repos: Repositories) -> int:
        await repos.sites.set_robots(SITE, ["explorer1"])
        registry = ChangedAfterEveryRead(repos.sites)
        with pytest.raises(StaleRevision, match=SITE):
            await grant_listed(cast(SiteRegistry, registry), bus.api, bus.admin_url, SITE)
        return registry.reads

    # the first read, then one after each grant
    assert bus.with_store(churned) == 1 + CHANGE_ATTEMPTS

    async def settled(repos: Repositories) -> tuple[str, ...]:
        await grant_listed(repos.sites, bus.api, bus.admin_url, SITE)
        listed = await repos.sites.robots_of(SITE)
        assert listed is not None
        return listed.robots

    robots = bus.with_store(settled)
    granted = bus.api.get_permissions(bus.vhost, SITE)
    assert granted is not None
    assert granted["write"] == site_permissions(SITE, robots)[1], "once the list rests, it is granted"
