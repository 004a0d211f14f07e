"""Central's administration of its sites: the one place that assigns robots to a site, in the
store (who may forward for whom, :mod:`fleetbus.workers.store.sites`) and on the broker (what the
site's account may write, :func:`fleetbus.broker.sites.grant_site_robots`), together. A change
is computed from the site's list as it is when the change is made (compare-and-set on the list's
revision), and what it sends the site carries that revision, so the newest change always wins."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from collections.abc import Callable, Collection, Mapping, Sequence

import pika

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import grant_site_robots
from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import SITES_EXCHANGE, RobotKind, site_downlink_key
from fleetbus.schemas.site_changes import (
    SITE_CHANGE_TYPE,
    AnySiteChange,
    MissionChange,
    RobotAccount,
    RobotAccountRemoved,
)
from fleetbus.workers.store.missions import Mission, MissionStore
from fleetbus.workers.store.sites import ListChange, SiteRegistry, StaleRevision
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.team import change_service

log = logging.getLogger("fleetbus.sites")


Decide = Callable[[tuple[str, ...]], Collection[str]]
"""A change of a site's robots: from its list as read, the list it becomes."""

#: How often a change is computed again from a newer list before it gives up (each retry means
#: another change of the same site was made meanwhile).
CHANGE_ATTEMPTS = 10


async def revise(sites: SiteRegistry, site: str, decide: Decide) -> list[ListChange]:
    """Change ``site``'s list of robots to what ``decide`` makes of it, by compare-and-set on its
    revision: a list that changed after it was read is read again and ``decide`` applied to the
    newer one, so no change undoes another made meanwhile. What changed, ``site``'s list first."""
    validate_name(site)
    read = 0
    for _ in range(CHANGE_ATTEMPTS):
        listed = await sites.robots_of(site)
        read = listed.revision if listed else 0
        robots = sorted(set(decide(listed.robots if listed else ())))
        for robot in robots:
            validate_name(robot)
        try:
            return await sites.set_robots(site, robots, revision=read)
        except StaleRevision:
            continue
    raise StaleRevision(site, read)


async def grant_listed(
    sites: SiteRegistry,
    api: ManagementAPI,
    admin_url: str,
    site: str,
    returning: Mapping[str, RobotKind | None] | None = None,
) -> None:
    """Let ``site``'s account at central write for the robots of its list as the store has it now
    (``returning``: robots that left it, whose inboxes at central take notifications again), and
    again until the list did not change meanwhile: a change that granted an older list after a
    newer one was granted grants the newer one again. A list changed meanwhile
    :data:`CHANGE_ATTEMPTS` times in a row ends in :class:`StaleRevision`; the registry check
    grants the list it finds later."""
    vhost = vhost_of(admin_url)
    granted = await sites.robots_of(site)
    for _ in range(CHANGE_ATTEMPTS):
        robots = granted.robots if granted else ()
        back = {robot: kind for robot, kind in (returning or {}).items() if robot not in robots}
        await asyncio.to_thread(grant_site_robots, api, vhost, site, robots, back)
        now = await sites.robots_of(site)
        if now == granted:
            return
        granted = now
    raise StaleRevision(site, granted.revision if granted else 0)


async def assign_robots(
    sites: SiteRegistry,
    team: TeamStore,
    api: ManagementAPI,
    admin_url: str,
    site: str,
    robots: Collection[str] | Decide,
) -> list[ListChange]:
    """Make ``robots`` the robots of ``site`` (or what ``robots``, a :data:`Decide`, makes of its
    list as it is when the change is made; a robot of another site moves here, the other site's
    account loses it). At central, a site's wardens are out of service (the site's gate counts
    them, central's must not wait for them); one that leaves its site is back in service. What
    changed, ``site``'s list first."""
    decide: Decide = robots if callable(robots) else (lambda _listed: robots)  # type: ignore[assignment]
    changes = await revise(sites, site, decide)
    kinds = {robot.name: robot.kind for robot in await team.robots()}
    mine = changes[0]
    returning = {r: RobotKind(kinds[r]) if kinds.get(r) else None for r in mine.left}
    await grant_listed(sites, api, admin_url, site, returning)
    for other in changes[1:]:
        await grant_listed(sites, api, admin_url, other.site)
    # central's hazard gate must not wait for wardens that localise at their site only
    by = f"site {site}"
    for robot in mine.joined:
        if kinds.get(robot) == RobotKind.WARDEN.value:
            await change_service(team, admin_url, robot, False, by)
    for robot in mine.left:
        if kinds.get(robot) == RobotKind.WARDEN.value:
            await change_service(team, admin_url, robot, True, by)
    return changes


async def set_site_robots(
    sites: SiteRegistry,
    team: TeamStore,
    api: ManagementAPI,
    admin_url: str,
    site: str,
    robots: Collection[str] | Decide,
) -> tuple[tuple[str, ...], list[RobotAccount], list[str]]:
    """:func:`assign_robots`, then send each site concerned what changed for it, with its list's
    new revision: the accounts of the robots new to ``site``, and the removal of the robots a site
    no longer has (taken from ``site``, or moved here from another), whose copies the site then
    removes (``fleetbus site apply`` applies both). Returns the robots, the accounts sent and the
    robots removed from ``site``."""
    changes = await assign_robots(sites, team, api, admin_url, site, robots)
    mine = changes[0]
    accounts = await robot_accounts(team, api, mine.joined, mine.revision)
    await asyncio.to_thread(send_to_sites, admin_url, [site], accounts)
    for change in changes:
        await asyncio.to_thread(send_removals, admin_url, change.site, change.left, change.revision)
    return mine.robots, accounts, list(mine.left)


def send_removals(admin_url: str, site: str, robots: Collection[str], revision: int | None) -> None:
    """Tell ``site`` to remove its copies of ``robots``' accounts (they are no longer its own, as of
    its list's ``revision``)."""
    if robots:
        removals = [RobotAccountRemoved(name=name, revision=revision) for name in sorted(robots)]
        send_to_sites(admin_url, [site], removals)
        log.info("site %s told to remove the accounts of %s", site, ", ".join(sorted(robots)))


async def robot_accounts(
    team: TeamStore, api: ManagementAPI, robots: Collection[str], revision: int | None
) -> list[RobotAccount]:
    """The accounts of ``robots`` as central has them (those without an account are left out), for
    a site whose list is at ``revision``."""
    kinds = {robot.name: robot.kind for robot in await team.robots()}
    accounts = []
    for name in sorted(robots):
        user = api.get_user(name)
        if user is None:
            continue
        kind = kinds.get(name)
        accounts.append(
            RobotAccount(
                name=name,
                kind=RobotKind(kind) if kind else None,
                password_hash=user["password_hash"],
                hashing_algorithm=user.get("hashing_algorithm", "rabbit_password_hashing_sha256"),
                revision=revision,
            )
        )
    return accounts


def mission_change(mission: Mission) -> MissionChange:
    """The downlink message for ``mission`` as central's store has it."""
    return MissionChange(**dataclasses.asdict(mission))


def site_of(mission: Mission) -> str | None:
    """The site the mission belongs to (its plan's ``site``); None: every site's."""
    site = mission.plan.get("site")
    return str(site) if site else None


def goes_to(mission: Mission, sites: Collection[str]) -> list[str]:
    """Of ``sites``, those ``mission`` is sent to: its own site only, or every one."""
    site = site_of(mission)
    return sorted(sites) if site is None else [s for s in sorted(sites) if s == site]


async def mission_changes(store: MissionStore, site: str | None = None) -> list[MissionChange]:
    """Every mission as central's store has it (those ``site`` is sent), in creation order."""
    missions = await store.missions()
    return [mission_change(m) for m in missions if site is None or goes_to(m, [site])]


async def send_mission_to_sites(sites_: SiteRegistry, admin_url: str, mission: Mission) -> list[str]:
    """Send the mission as it is now (after central created or changed it) to its site, or to
    every site when it names none; the sites it went to. A mission naming a site central does not
    know goes nowhere (logged)."""
    known = await sites_.sites()
    sites = goes_to(mission, known)
    if not sites and site_of(mission) is not None:
        log.warning("mission %s names site %s, unknown at central", mission.mission_id, site_of(mission))
    await asyncio.to_thread(send_to_sites, admin_url, sites, [mission_change(mission)])
    return sites


def send_to_sites(admin_url: str, sites: Sequence[str], changes: Sequence[AnySiteChange]) -> None:
    """Publish ``changes`` to each site's downlink, over one connection (persistent, confirmed: the
    shovel takes them on whenever the site is connected)."""
    connection = pika.BlockingConnection(pika_parameters(admin_url))
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for site in sites:
            for change in changes:
                channel.basic_publish(
                    SITES_EXCHANGE,
                    site_downlink_key(site, change.change),
                    change.model_dump_json().encode(),
                    pika.BasicProperties(
                        delivery_mode=2, content_type="application/json", type=SITE_CHANGE_TYPE
                    ),
                    mandatory=True,
                )
    finally:
        connection.close()
