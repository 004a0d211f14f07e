"""Central's administration of its sites: the one place that assigns robots to a site, in the
store (who may forward for whom, :mod:`fleetbus.workers.store.sites`) and on the broker (what the
site's account may write, :func:`fleetbus.broker.sites.grant_site_robots`), together."""

from __future__ import annotations

from collections.abc import Collection

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import grant_site_robots
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store import Repositories


async def assign_robots(
    repositories: Repositories, api: ManagementAPI, admin_url: str, site: str, robots: Collection[str]
) -> tuple[str, ...]:
    """Make ``robots`` exactly the robots of ``site`` (a robot of another site moves here; the
    other site's account loses it). Returns them, sorted."""
    validate_name(site)
    for robot in robots:
        validate_name(robot)
    before = await repositories.sites.sites()
    old = set(before.get(site, ()))
    new = set(robots)
    moved_from = {other for other, members in before.items() if other != site and new & set(members)}
    await repositories.sites.set_robots(site, sorted(new))
    kinds = {robot.name: robot.kind for robot in await repositories.hazards.robots()}
    returning = {r: RobotKind(kinds[r]) if kinds.get(r) else None for r in old - new}
    vhost = vhost_of(admin_url)
    grant_site_robots(api, vhost, site, sorted(new), returning)
    after = await repositories.sites.sites()
    for other in moved_from:
        grant_site_robots(api, vhost, other, after.get(other, ()))
    return tuple(sorted(new))
