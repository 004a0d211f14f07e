"""The account registry against what derives from it: the broker's accounts, permissions, topic
permissions and ingest-shard bindings, the team, each site's account at central, and the
robots' accounts each site has (as its newest report says: central does not reach the sites'
brokers; a site reports from ``fleetbus site apply``). Each
difference is a :class:`Drift`; :meth:`AccountCheck.repair` makes the derived state the
registry's again (the registry itself changes only to take in a broker account made outside it).

The broker's users are broker-wide; the check looks at the accounts that have permissions in the
registry's virtual host (one with none can do nothing there) and leaves out the administrator, the
service's own accounts (``fleetbus*``) and the sites' accounts, which it checks as sites.
"""

from __future__ import annotations

import asyncio
from collections.abc import Collection
from dataclasses import asdict, dataclass
from typing import Any, Literal, get_args
from urllib.parse import unquote, urlsplit

from fleetbus.api.services.accounts import Accounts, broker_role
from fleetbus.broker.accounts import TOPIC_PATTERN, confined_permissions, keyed_exchanges, vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.shards import read_shard_map, unassign_shard
from fleetbus.broker.sites import site_permissions
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import SERVICE_PREFIX, beacon_exchange
from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.site_report_collector import collect_site_reports
from fleetbus.workers.sites import grant_listed, revise
from fleetbus.workers.store import Repositories
from fleetbus.workers.store.sites import SiteRegistry
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.store.users import User, UserStore
from fleetbus.workers.team import leave_team

#: What a drift is about, in the order they are listed and repaired.
DriftKind = Literal["outside", "account", "permissions", "topic-permissions", "shard", "team", "site"]
KINDS: tuple[str, ...] = get_args(DriftKind)


@dataclass(frozen=True)
class Drift:
    kind: DriftKind
    name: str
    """The user, robot or site it is about."""
    problem: str
    """What differs, for a person to read."""
    repair: str
    """What ``repair`` does about it."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class _Broker:
    """What the broker has, read once."""

    users: dict[str, dict[str, Any]]
    permissions: dict[str, tuple[str, str, str]]
    topics: dict[str, dict[str, tuple[str, str]]]
    shards: dict[str, tuple[int, ...]]


class AccountCheck:
    def __init__(
        self,
        accounts: Accounts,
        users: UserStore,
        team: TeamStore,
        sites: SiteRegistry,
        management: ManagementAPI,
        admin_url: str,
        shards: int,
    ) -> None:
        self._accounts = accounts
        self._users = users
        self._team = team
        self._sites = sites
        self._management = management
        self._admin_url = admin_url
        self._vhost = vhost_of(admin_url)
        self._shards = shards

    def _read_broker(self) -> _Broker:
        api, vhost = self._management, self._vhost
        permissions = {
            p["user"]: (p["configure"], p["write"], p["read"]) for p in api.list_permissions(vhost)
        }
        topics: dict[str, dict[str, tuple[str, str]]] = {}
        for t in api.list_topic_permissions(vhost):
            topics.setdefault(t["user"], {})[t["exchange"]] = (t["write"], t["read"])
        return _Broker(
            {u["name"]: u for u in api.list_users()},
            permissions,
            topics,
            dict(read_shard_map(api, vhost, self._shards).bindings),
        )

    def _not_users(self, sites: Collection[str]) -> set[str]:
        admin = unquote(urlsplit(self._admin_url).username or "")
        return {admin, *sites}

    async def drift(self) -> list[Drift]:
        """Every difference between the registry and what derives from it, by kind and name."""
        registry = {user.name: user for user in await self._users.users()}
        team = {robot.name: robot.kind for robot in await self._team.robots()}
        sites = await self._sites.sites()
        copies = await self._site_copies()
        broker = await asyncio.to_thread(self._read_broker)
        found: list[Drift] = []
        skip = self._not_users(sites)
        outside = {
            name
            for name in broker.permissions.keys() - registry.keys() - skip
            if not name.startswith(SERVICE_PREFIX) and name in broker.users
        }
        for name in sorted(outside):
            role, _ = self._guess_role(name, broker)
            found.append(
                Drift(
                    "outside",
                    name,
                    f"broker account {name} is not in the registry",
                    f"take it in as a {role.value}, its password kept",
                )
            )
        for user in registry.values():
            found.extend(self._user_drift(user, broker))
        robots = {name for name, user in registry.items() if user.role is UserRole.ROBOT}
        # what an account outside the registry has comes with it when it is taken in
        for name in sorted(broker.shards.keys() - robots - outside):
            found.append(
                Drift("shard", name, f"{name} is bound to an ingest shard but is no robot", "unbind it")
            )
        for name in sorted(robots):
            if name not in team:
                found.append(Drift("team", name, f"robot {name} is not in the team", "add it to the team"))
            elif team[name] != registry[name].kind:
                found.append(
                    Drift(
                        "team",
                        name,
                        f"robot {name} is a {registry[name].kind or 'robot of no kind'} in the registry, "
                        f"a {team[name] or 'robot of no kind'} in the team",
                        "give the team the registry's kind",
                    )
                )
        for name in sorted(team.keys() - robots - outside):
            found.append(
                Drift("team", name, f"{name} is in the team but is no robot", "take it out of the team")
            )
        for site, members in sorted(sites.items()):
            found.extend(self._copies_drift(site, members, copies.get(site)))
            found.extend(self._site_drift(site, members, robots, broker))
        return sorted(found, key=lambda d: (KINDS.index(d.kind), d.name))

    def _guess_role(self, name: str, broker: _Broker) -> tuple[UserRole, str | None]:
        """The role of a broker account made outside the registry, as its permissions tell."""
        if beacon_exchange(name) in broker.topics.get(name, {}):
            return UserRole.ROBOT, None
        tags = broker.users[name].get("tags") or []
        return (UserRole.OPERATOR if "management" in tags else UserRole.GUEST), None

    def _user_drift(self, user: User, broker: _Broker) -> list[Drift]:
        name = user.name
        if name not in broker.users:
            return [
                Drift("account", name, f"{name} has no broker account", "make it again, with a new password")
            ]
        found = []
        active = user.role is not UserRole.INACTIVE
        expected = confined_permissions(name) if active else None
        has = broker.permissions.get(name)
        if has != expected:
            found.append(
                Drift(
                    "permissions",
                    name,
                    f"{name}'s permissions are {has or 'none'}, its role {user.role.value} has "
                    f"{expected or 'none'}",
                    "grant what its role has",
                )
            )
        wanted = (
            {
                exchange: (TOPIC_PATTERN, TOPIC_PATTERN)
                for exchange in keyed_exchanges(name, broker_role(user.role))
            }
            if active
            else {}
        )
        topics = broker.topics.get(name, {})
        if active and any(topics.get(exchange) != keys for exchange, keys in wanted.items()):
            missing = sorted(e for e, keys in wanted.items() if topics.get(e) != keys)
            found.append(
                Drift(
                    "topic-permissions",
                    name,
                    f"{name} lacks its own routing keys on {', '.join(missing)}",
                    "grant them",
                )
            )
        if user.role is UserRole.ROBOT:
            bound = broker.shards.get(name, ())
            if len(bound) != 1 or bound[0] >= self._shards:
                where = ", ".join(map(str, bound)) or "none"
                found.append(
                    Drift(
                        "shard",
                        name,
                        f"robot {name} is bound to shards {where}, not to one of {self._shards}",
                        "bind it to one (the least loaded when it has none)",
                    )
                )
        return found

    async def _site_copies(self) -> dict[str, SiteReport]:
        """Each site's newest report (those waiting at central taken in first): the robots'
        accounts it has, as it last said."""
        await collect_site_reports(self._admin_url, self._sites)
        return await self._sites.reports()

    def _copies_drift(self, site: str, members: Collection[str], report: SiteReport | None) -> list[Drift]:
        """The copies of robots' accounts the site has (as its newest report says) but should not:
        robots removed at central, or taken from the site."""
        extra = extra_copies(members, report)
        if not extra:
            return []
        assert report is not None
        held = [report.in_use[name] for name in extra if name in (report.in_use or {})]
        refused = f"; it refuses to remove them while they are in use: {'; '.join(held)}" if held else ""
        return [
            Drift(
                "site",
                site,
                f"site {site} keeps the accounts of {', '.join(extra)}, which are not its robots "
                f"(its report of {report.at:%Y-%m-%d %H:%M:%S} UTC){refused}",
                "tell the site to remove them",
            )
        ]

    def _site_drift(
        self, site: str, members: Collection[str], robots: set[str], broker: _Broker
    ) -> list[Drift]:
        unknown = sorted(set(members) - robots)
        if unknown:
            return [
                Drift(
                    "site",
                    site,
                    f"site {site}'s robots {', '.join(unknown)} are not robots in the registry",
                    "take them from the site",
                )
            ]
        if site not in broker.users:
            return [
                Drift(
                    "site",
                    site,
                    f"site {site} has no account at central",
                    "none: `fleetbus sites add --rotate`",
                )
            ]
        expected = site_permissions(site, members)
        if broker.permissions.get(site) != expected:
            return [
                Drift(
                    "site",
                    site,
                    f"site {site}'s permissions are not its robots' ({', '.join(members) or 'none'})",
                    "grant it its robots",
                )
            ]
        return []

    async def repair(self, by: str) -> list[Drift]:
        """Repair every drift found; what was found (check again to see what is left)."""
        found = await self.drift()
        registry = {user.name: user for user in await self._users.users()}
        sites = await self._sites.sites()
        broker = await asyncio.to_thread(self._read_broker)
        reports = await self._sites.reports()
        repaired: set[tuple[str, str]] = set()
        for drift in found:
            if (drift.kind, drift.name) not in repaired:  # a site's drifts are repaired at once
                await self._repair(drift, registry, sites, reports, broker, by)
                repaired.add((drift.kind, drift.name))
        return found

    async def _repair(
        self,
        drift: Drift,
        registry: dict[str, User],
        sites: dict[str, tuple[str, ...]],
        reports: dict[str, SiteReport],
        broker: _Broker,
        by: str,
    ) -> None:
        name = drift.name
        if drift.kind == "outside":
            role, kind = self._guess_role(name, broker)
            registry[name] = await self._accounts.adopt(name, role, kind, by)
        elif drift.kind in ("account", "permissions", "topic-permissions") or (
            drift.kind == "shard" and name in registry and registry[name].role is UserRole.ROBOT
        ):
            await self._accounts.align(registry[name], by)
        elif drift.kind == "shard":
            await asyncio.to_thread(unassign_shard, self._management, self._vhost, name)
        elif drift.kind == "team":
            user = registry.get(name)
            if user is not None and user.role is UserRole.ROBOT:
                await self._team.register_robot(name, user.kind)
            else:
                await leave_team(self._team, self._admin_url, name, by)
        elif drift.kind == "site":
            robots = {n for n, u in registry.items() if u.role is UserRole.ROBOT}
            members = [robot for robot in sites.get(name, ()) if robot in robots]
            if site_exists(name, broker):  # its robots as they are now, the registry's only
                changes = await revise(self._sites, name, lambda listed: [r for r in listed if r in robots])
                await grant_listed(self._sites, self._management, self._admin_url, name)
                members = list(changes[0].robots)
            if extra := extra_copies(members, reports.get(name)):
                await self._accounts.tell_site_to_remove(name, extra)


def site_exists(site: str, broker: _Broker) -> bool:
    return site in broker.users


def extra_copies(members: Collection[str], report: SiteReport | None) -> list[str]:
    """The robots whose accounts the site has, as ``report`` says, that are not its ``members``."""
    if report is None or report.accounts is None:
        return []
    return sorted(set(report.accounts) - set(members))


def account_check_for(
    accounts: Accounts, repositories: Repositories, management: ManagementAPI, admin_url: str, shards: int
) -> AccountCheck:
    """The check as the HTTP API, the console and the command line all use it."""
    return AccountCheck(
        accounts, repositories.users, repositories.hazards, repositories.sites, management, admin_url, shards
    )
