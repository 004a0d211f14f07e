"""Central's administration of its sites: the one place that assigns robots to a site, in the
store (who may forward for whom, :mod:`fleetbus.workers.store.sites`) and on the broker (what the
site's account may write, :func:`fleetbus.broker.sites.grant_site_robots`), together."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from collections.abc import Collection, Sequence

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
from fleetbus.workers.store.sites import SiteRegistry
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.team import change_service

log = logging.getLogger("fleetbus.sites")


async def assign_robots(
    sites: SiteRegistry,
    team: TeamStore,
    api: ManagementAPI,
    admin_url: str,
    site: str,
    robots: Collection[str],
) -> tuple[str, ...]:
    """Make ``robots`` exactly the robots of ``site`` (a robot of another site moves here; the
    other site's account loses it). At central, a site's wardens are out of service (the site's
    gate counts them, central's must not wait for them); one that leaves its site is back in
    service. Returns the robots, sorted."""
    validate_name(site)
    for robot in robots:
        validate_name(robot)
    before = await sites.sites()
    old = set(before.get(site, ()))
    new = set(robots)
    moved_from = {other for other, members in before.items() if other != site and new & set(members)}
    await sites.set_robots(site, sorted(new))
    kinds = {robot.name: robot.kind for robot in await team.robots()}
    returning = {r: RobotKind(kinds[r]) if kinds.get(r) else None for r in old - new}
    vhost = vhost_of(admin_url)
    grant_site_robots(api, vhost, site, sorted(new), returning)
    after = await sites.sites()
    for other in moved_from:
        grant_site_robots(api, vhost, other, after.get(other, ()))
    # central's hazard gate must not wait for wardens that localise at their site only
    by = f"site {site}"
    for robot in sorted(new - old):
        if kinds.get(robot) == RobotKind.WARDEN.value:
            await change_service(team, admin_url, robot, False, by)
    for robot in sorted(old - new):
        if kinds.get(robot) == RobotKind.WARDEN.value:
            await change_service(team, admin_url, robot, True, by)
    return tuple(sorted(new))


async def set_site_robots(
    sites: SiteRegistry,
    team: TeamStore,
    api: ManagementAPI,
    admin_url: str,
    site: str,
    robots: Collection[str],
) -> tuple[tuple[str, ...], list[RobotAccount], list[str]]:
    """:func:`assign_robots`, then send each site concerned what changed for it: the accounts of
    the robots new to ``site``, and the removal of the robots a site no longer has (taken from
    ``site``, or moved here from another), whose copies the site then removes (``fleetbus site
    apply`` applies both). Returns the robots, the accounts sent and the robots removed from
    ``site``."""
    before = await sites.sites()
    names = await assign_robots(sites, team, api, admin_url, site, robots)
    accounts = await robot_accounts(team, api, set(names) - set(before.get(site, ())))
    await asyncio.to_thread(send_to_sites, admin_url, [site], accounts)
    gone: list[str] = []
    for other, members in before.items():
        left = sorted(set(members) - set(names)) if other == site else sorted(set(members) & set(names))
        await asyncio.to_thread(send_removals, admin_url, other, left)
        if other == site:
            gone = left
    return names, accounts, gone


def send_removals(admin_url: str, site: str, robots: Collection[str]) -> None:
    """Tell ``site`` to remove its copies of ``robots``' accounts (they are no longer its own)."""
    if robots:
        send_to_sites(admin_url, [site], [RobotAccountRemoved(name=name) for name in sorted(robots)])
        log.info("site %s told to remove the accounts of %s", site, ", ".join(sorted(robots)))


async def robot_accounts(team: TeamStore, api: ManagementAPI, robots: Collection[str]) -> list[RobotAccount]:
    """The accounts of ``robots`` as central has them (those without an account are left out)."""
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
