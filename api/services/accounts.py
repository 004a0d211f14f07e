"""The account registry's one application service: create, change role, remove, log in; each user
with its broker account. The command line (``fleetbus users``), the HTTP API (``/users``) and the
console's Accounts page are adapters of it: the same checks, the same refusals
(:mod:`fleetbus.api.services.errors`), the same outcome. So is ``fleetbus sites add | robots``: a site's
account at central forwards for robots of the registry, and a robot removed or taken from a site
is removed from the site's broker too (over the downlink).

The store holds the user (role, password hash, encrypted broker password); the broker holds an
account of the same name with a random password, confined to ``^<name>\\.``. The store is
written first, so a name is claimed atomically; a broker failure then undoes the store write.
An ``inactive`` user's broker account has no permissions at all: it cannot even connect.
Client certificates fleetbus's CA signed for a name are revoked when a user of that name is made or
removed: a later account of that name must not inherit them. A password set, a user disabled and
a user removed end the user's login sessions (but the one that changed its own password).
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from collections.abc import AsyncIterator, Callable, Collection, Iterable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from urllib.parse import unquote, urlsplit

from pika.exceptions import AMQPError

from fleetbus.api.services.errors import BadRequest, Conflict, Forbidden, NotFound, Unavailable
from fleetbus.api.services.security import Secrets, Token, password_problem
from fleetbus.api.services.sessions import Origin, Sessions, end_sessions_of
from fleetbus.broker.account_roles import ROLE_TAGS, Role
from fleetbus.broker.accounts import (
    as_public,
    configure_account,
    delete_account,
    drop_other_roles,
    revoke_account,
    url_for,
    vhost_of,
)
from fleetbus.broker.certificates import CertificateError, TlsFiles
from fleetbus.broker.fleet import NewRobot, provision_robots
from fleetbus.broker.management import ManagementAPI, ManagementError
from fleetbus.broker.revocation import cannot_revoke, revoke_certificates_of, revoked_summary
from fleetbus.broker.sites import add_site_account, central_site_topology
from fleetbus.broker.team_changes import HazardServiceNotTold
from fleetbus.broker.topology import declare_with_url
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.site_changes import RobotAccount, RobotRoster
from fleetbus.schemas.use_cases import USE_CASES
from fleetbus.settings import Settings
from fleetbus.workers.account_use import in_use
from fleetbus.workers.sites import (
    Decide,
    grant_listed,
    revise,
    robot_accounts,
    send_removals,
    send_to_sites,
    set_site_robots,
)
from fleetbus.workers.store import Repositories, open_repositories
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.sites import SiteRegistry, StaleRevision
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.store.users import User, UserExists, UserStore
from fleetbus.workers.team import leave_team

log = logging.getLogger("fleetbus.api.accounts")

#: What kind of broker account each role gets (it decides the queues and exchanges it owns).
BROKER_ROLE: dict[UserRole, Role] = {
    UserRole.ROBOT: Role.ROBOT,
    UserRole.OPERATOR: Role.OPERATOR,
    UserRole.SUPERVISOR: Role.OPERATOR,
}


def broker_role(role: UserRole) -> Role:
    return BROKER_ROLE.get(role, Role.USER)


@dataclass(frozen=True)
class BrokerCredentials:
    username: str
    password: str
    vhost: str
    amqp_url: str


@dataclass(frozen=True)
class Provisioned:
    user: User
    internal_url: str
    """Its broker URL as this service reaches the broker (no password for a certificate's login)."""
    public_url: str
    """The same login at the broker's public address: what the user or robot is handed, once."""
    revoked: str | None = None
    """The certificates of the name revoked, said in a sentence (None: there were none)."""


@dataclass(frozen=True)
class Removed:
    left_team: bool
    """It was a robot of the team."""
    revoked: str | None = None
    """The certificates of the name revoked, said in a sentence (None: there were none)."""


@dataclass(frozen=True)
class SiteRobots:
    robots: tuple[str, ...]
    """The site's robots now, sorted."""
    sent: list[RobotAccount]
    """The accounts sent to the site (of the robots new to it)."""
    removed: list[str]
    """The robots the site was told to remove its copies of."""


@dataclass(frozen=True)
class SiteAdded(SiteRobots):
    public_url: str = ""
    """The site's login at central's public address: what its operator is handed, once."""
    internal_url: str = ""
    """The same login as this service reaches central's broker."""


@dataclass(frozen=True)
class Login:
    user: User
    token: Token
    broker: BrokerCredentials


class Accounts:
    def __init__(
        self,
        users: UserStore,
        team: TeamStore,
        channels: ChannelStore,
        secrets_: Secrets,
        sessions: Sessions,
        management: ManagementAPI,
        admin_url: str,
        shards: int = 1,
        public_url: str | None = None,
        *,
        cluster: bool = False,
        certificates: TlsFiles | None = None,
        sites: SiteRegistry | None = None,
    ) -> None:
        """``public_url``: the broker as users and robots reach it (no credentials), for the URLs
        handed out; None: ``admin_url``'s broker. ``certificates``: fleetbus's CA, whose
        certificates for a name are revoked when a user of that name is made or removed.
        ``sites``: the sites, whose accounts at central no user may take the name of."""
        self._certificates = certificates
        self._sites = sites
        self._public_url = public_url
        self._users = users
        self._team = team
        self._channels = channels
        self._shards = shards
        self._cluster = cluster
        self._secrets = secrets_
        self._sessions = sessions
        self._management = management
        self._admin_url = admin_url

    async def _broker(
        self,
        name: str,
        role: UserRole,
        kind: str | None,
        password: str | None = None,
        *,
        certificate: bool = False,
    ) -> None:
        """Bring the broker account in line with the role (and set its password when given;
        ``certificate``: make it log in without one)."""

        def apply() -> None:
            if password is not None:
                self._management.put_user(name, password, ROLE_TAGS[broker_role(role)])
            elif certificate:
                self._management.put_user_without_password(name, ROLE_TAGS[broker_role(role)])
            if role is UserRole.INACTIVE:
                revoke_account(self._admin_url, self._management, name)
            else:
                robot_kind = RobotKind(kind) if kind else None
                asyncio.run(
                    configure_account(
                        self._admin_url,
                        self._management,
                        name,
                        broker_role(role),
                        robot_kind,
                        shards=self._shards,
                        cluster=self._cluster,
                    )
                )

        try:
            await asyncio.to_thread(apply)
        except (ManagementError, OSError) as error:
            raise Unavailable(f"the broker refused or failed to set up account {name!r}: {error}") from error

    async def align(self, user: User, by: str) -> None:
        """Bring ``user``'s broker account in line with the registry: remake it when it is missing
        (a new broker password, kept sealed in the registry, or none for a certificate's login),
        else its tags, permissions, exchanges and shard as its role has them."""
        if await asyncio.to_thread(self._management.get_user, user.name) is None:
            password = None if user.broker_secret is None else secrets.token_urlsafe(24)
            certificate = password is None
            await self._broker(user.name, user.role, user.kind, password=password, certificate=certificate)
            if password is not None:
                await self._users.update_user(
                    user.name, datetime.now(timezone.utc), broker_secret=self._secrets.box.seal(password)
                )
            log.warning("user %s: broker account made again by %s", user.name, by)
        else:
            await self._broker(user.name, user.role, user.kind)

    async def adopt(self, name: str, role: UserRole, kind: str | None, by: str) -> User:
        """Record a broker account made outside the registry, as it is (its password stays: the
        URL handed out before still logs in; the registry has none to hand out until a reset)."""
        now = datetime.now(timezone.utc)
        user = User(name, role, None, None, kind, now, f"{by} (taken in from the broker)", now)
        try:
            await self._users.add_user(user)
        except UserExists:
            raise Conflict(f"user {name!r} exists") from None
        if role is UserRole.ROBOT:
            await self._team.register_robot(name, kind)
        log.warning("user %s: broker account taken into the registry by %s", name, by)
        return user

    async def _check_revocable(self, name: str) -> None:
        """Refuse before anything changes when ``name``'s certificates could not be revoked."""
        if self._certificates is not None:
            if problem := await asyncio.to_thread(cannot_revoke, self._certificates, name):
                raise Unavailable(problem)

    async def _revoke_certificates(self, name: str) -> str | None:
        """Revoke ``name``'s certificates; what was revoked, said in a sentence (None: none)."""
        if self._certificates is None:
            return None
        try:
            revoked = await asyncio.to_thread(revoke_certificates_of, self._certificates, name)
        except CertificateError as error:
            raise Unavailable(f"could not revoke the certificates of {name}: {error}") from error
        if not revoked:
            return None
        summary = revoked_summary(name, revoked)
        log.info("%s", summary)
        return summary

    async def _check_name(self, name: str) -> None:
        """Refuse a name no user may have: an invalid or reserved one (``fleetbus*``, ``amq*``,
        ``guest*``), the broker administrator's own, or a site's account at central."""
        try:
            validate_name(name)
        except ValueError as error:
            raise BadRequest(str(error)) from None
        if name == unquote(urlsplit(self._admin_url).username or ""):
            raise BadRequest(f"{name!r} is the broker administrator's account: no user may have that name")
        if self._sites is not None and name in await self._sites.sites():
            raise BadRequest(f"{name!r} is a site's account at central: no user may have that name")

    async def create(
        self, name: str, password: str | None, role: UserRole, kind: RobotKind | None, by: str
    ) -> User:
        """A new user and its broker account; ``password`` ``None``: cannot log in until one is set."""
        return (await self.provision(name, role, kind, by, password=password)).user

    async def provision(
        self,
        name: str,
        role: UserRole | None,
        kind: RobotKind | None,
        by: str,
        *,
        password: str | None = None,
        rotate: bool = False,
        certificate: bool = False,
    ) -> Provisioned:
        """Record ``name`` in the registry and make its broker account (with its permissions,
        exchanges, inbox, and a robot's shard and place in the team); revoke the certificates the
        CA signed for the name. ``rotate``: an existing user (or a broker account made outside the
        registry, which it then records) gets a new broker password, and the role and kind given;
        ``role`` None: a new account is a robot, a re-keyed one keeps its role, and its kind too
        when ``kind`` is None.
        ``certificate``: the broker account has no password (it logs in with a client certificate).
        ``password`` is the HTTP API login's (``None``: none yet)."""
        await self._check_name(name)
        if password is not None and (problem := password_problem(password)):
            raise BadRequest(problem)
        existing = await self._users.get_user(name)
        if role is None:
            keeps = existing if rotate else None  # re-keyed: its password changes, nothing else
            role = keeps.role if keeps is not None else UserRole.ROBOT
            if keeps is not None and kind is None and keeps.kind:
                kind = RobotKind(keeps.kind)
        if kind is not None and role is not UserRole.ROBOT:
            raise BadRequest("kind applies to robots only")
        if not rotate:
            if existing is not None:
                raise Conflict(f"user {name!r} exists")
            if await asyncio.to_thread(self._management.get_user, name) is not None:
                raise Conflict(
                    f"a broker account named {name!r} exists outside the service; remove it first "
                    "(or give it a new password with `fleetbus users add NAME --rotate`)"
                )
        await self._check_revocable(name)
        broker_password = None if certificate else secrets.token_urlsafe(24)
        hashed = await self._secrets.passwords.hash(password) if password is not None else None
        user = self._record(name, role, kind, broker_password, existing, by, hashed)
        if existing is None:
            try:
                await self._users.add_user(user)
            except UserExists:
                raise Conflict(f"user {name!r} exists") from None
        try:
            await self._broker(name, role, user.kind, password=broker_password, certificate=certificate)
        except Unavailable:
            if existing is None:
                await self._users.remove_user(name)
                await asyncio.to_thread(self._management.delete_user, name)
            raise
        if existing is not None:
            await self._drop_earlier_role(name, existing.role, role, user.kind)
            await self._users.put_user(user)
        if role is UserRole.ROBOT:
            await self._team.register_robot(name, user.kind)
        revoked = await self._revoke_certificates(name)
        log.info("user %s %s by %s with role %s", name, "re-keyed" if existing else "created", by, role.value)
        url = url_for(self._admin_url, name, broker_password)
        return Provisioned(user, url, as_public(url, self._public_url), revoked)

    async def provision_robots(
        self, robots: Sequence[NewRobot], by: str, *, rotate: bool = False
    ) -> list[Provisioned]:
        """Many robots at once, each as :meth:`provision` makes one (its registry record, broker
        account, shard and place in the team; its certificates revoked), their broker accounts in
        one definitions import per 500. Refused, changing nothing, when a name is invalid or
        reserved, or (without ``rotate``) taken."""
        for robot in robots:
            await self._check_name(robot.name)
        names = {robot.name for robot in robots}
        recorded = {user.name: user for user in await self._users.users() if user.name in names}
        if not rotate:
            on_broker = {u["name"] for u in await asyncio.to_thread(self._management.list_users)}
            if taken := sorted(recorded.keys() | (on_broker & names)):
                shown = ", ".join(taken[:5]) + (", ..." if len(taken) > 5 else "")
                raise Conflict(
                    f"{len(taken)} exist already ({shown}); use --rotate to give them new passwords"
                )
        for robot in robots:
            await self._check_revocable(robot.name)
        try:
            accounts = await provision_robots(
                self._admin_url,
                self._management,
                robots,
                rotate=rotate,
                shards=self._shards,
                cluster=self._cluster,
            )
        except ValueError as error:
            raise BadRequest(str(error)) from None
        except (ManagementError, OSError) as error:
            raise Unavailable(f"the broker refused or failed to make the accounts: {error}") from error
        kinds = {robot.name: robot.kind for robot in robots}
        made = []
        for account in accounts:
            kind = kinds[account.name]
            password = unquote(urlsplit(account.amqp_url).password or "")
            user = self._record(account.name, UserRole.ROBOT, kind, password, recorded.get(account.name), by)
            await self._users.put_user(user)
            await self._team.register_robot(account.name, user.kind)
            revoked = await self._revoke_certificates(account.name)
            public = as_public(account.amqp_url, self._public_url)
            made.append(Provisioned(user, account.amqp_url, public, revoked))
        log.info("%d robots made by %s", len(made), by)
        return made

    def _record(
        self,
        name: str,
        role: UserRole,
        kind: RobotKind | None,
        broker_password: str | None,
        existing: User | None,
        by: str,
        password_hash: str | None = None,
    ) -> User:
        """The registry's record of ``name`` (a new one, or ``existing`` re-keyed)."""
        now = datetime.now(timezone.utc)
        return User(
            name=name,
            role=role,
            password_hash=password_hash or (existing.password_hash if existing else None),
            broker_secret=self._secrets.box.seal(broker_password) if broker_password else None,
            kind=kind.value if kind else None,
            created_at=existing.created_at if existing else now,
            created_by=existing.created_by if existing else by,
            updated_at=now,
            use_cases=existing.use_cases if existing else None,
        )

    async def get(self, name: str) -> User:
        user = await self._users.get_user(name)
        if user is None:
            raise NotFound(f"no user {name!r}")
        return user

    async def listed(self, viewer: User, role: UserRole | None = None) -> list[User]:
        """The accounts ``viewer`` may see, by name (optionally of one role): every one for an
        admin, the robots for a supervisor (whose missions they serve)."""
        return await self._users.users(_seen_role(viewer, role))

    async def seen(self, viewer: User, name: str) -> User:
        """``name``'s account, if ``viewer`` may see it (as :meth:`listed`)."""
        user = await self.get(name)
        _seen_role(viewer, user.role)
        return user

    async def _drop_earlier_role(self, name: str, was: UserRole, role: UserRole, kind: str | None) -> None:
        """What the broker account had for its earlier role and not for this one (an operator's
        stream, say); the inactive role's revocation drops it itself."""
        if role is UserRole.INACTIVE or broker_role(was) is broker_role(role):
            return
        vhost, robot_kind = vhost_of(self._admin_url), RobotKind(kind) if kind else None
        await asyncio.to_thread(
            drop_other_roles, self._management, vhost, name, broker_role(role), robot_kind
        )

    async def set_role(self, name: str, role: UserRole, by: str) -> User:
        """Give ``name`` another role (``inactive`` disables it); ``by`` is the admin who does it."""
        if name == by and role is not UserRole.ADMIN:
            raise BadRequest("an admin cannot take its own admin role away (ask another admin)")
        user = await self.get(name)
        if user.kind is not None and role is not UserRole.ROBOT and role is not UserRole.INACTIVE:
            raise BadRequest(f"{name} is a robot ({user.kind}); it can be a robot or inactive")
        leaving = broker_role(user.role) is Role.OPERATOR and broker_role(role) is not Role.OPERATOR
        if leaving and (problem := await in_use(self._channels, name)):
            raise Conflict(f"{problem} (its mounts are an operator's)")
        await self._broker(name, role, user.kind)
        await self._drop_earlier_role(name, user.role, role, user.kind)
        changed = await self._users.update_user(name, datetime.now(timezone.utc), role=role)
        if role is UserRole.INACTIVE:  # else they would open again when it is given a role
            await self._sessions.end_all(name)
        if role is not user.role:  # its open connections keep what they were allowed: they end
            reason = f"{name}'s role changed to {role.value}"
            await asyncio.to_thread(self._management.close_connections_of, name, reason)
        log.info("user %s: role %s -> %s, by %s", name, user.role.value, role.value, by)
        return changed

    async def set_use_cases(self, name: str, use_cases: Sequence[str] | None, by: str) -> User:
        """Let ``name`` create missions of these use cases only (``None``: of every one, those
        added later too); :func:`fleetbus.api.services.missions.use_case_refusal` is the rule that
        reads them."""
        allowed = None if use_cases is None else known_use_cases(use_cases)
        await self.get(name)
        changed = await self._users.set_use_cases(name, allowed, datetime.now(timezone.utc))
        shown = "every use case" if allowed is None else ", ".join(allowed) or "no use case"
        log.info("user %s: allowed %s, by %s", name, shown, by)
        return changed

    async def set_password(self, name: str, password: str, keep: str | None = None) -> User:
        """Set ``name``'s password and end its sessions but ``keep`` (the one that changed it)."""
        if problem := password_problem(password):
            raise BadRequest(problem)
        await self.get(name)
        changed = await self._users.update_user(
            name, datetime.now(timezone.utc), password_hash=await self._secrets.passwords.hash(password)
        )
        ended = await self._sessions.end_all(name, keep=keep)
        log.info("user %s: password set; %d other session(s) ended", name, ended)
        return changed

    async def change_own_password(self, user: User, current: str, new: str, keep: str) -> User:
        """``user`` changes its own password, given the current one; its sessions but ``keep`` end."""
        if not await self._secrets.passwords.verify(user.password_hash, current):
            raise BadRequest("the current password is wrong")
        return await self.set_password(user.name, new, keep=keep)

    async def end_sessions(self, name: str, by: str, keep: str | None = None) -> int:
        """End every login session of ``name`` (but ``keep``); how many ended."""
        return await end_sessions_of(self._users, self._sessions.store, name, by, keep)

    async def reset_broker_password(self, name: str, by: str) -> BrokerCredentials:
        """Give the user's broker account a new random password; the old one no longer logs in
        (connections already open stay open). The store is written first and put back if the
        broker refuses, so the password the login hands out is always the broker's."""
        user = await self.get(name)
        password = secrets.token_urlsafe(24)
        rekeyed = await self._users.update_user(
            name, datetime.now(timezone.utc), broker_secret=self._secrets.box.seal(password)
        )
        try:
            await self._broker(name, user.role, user.kind, password=password)
        except Unavailable:
            await self._users.update_user(name, datetime.now(timezone.utc), broker_secret=user.broker_secret)
            raise
        log.info("user %s: broker password reset by %s", name, by)
        return self.broker_credentials(rekeyed)

    async def remove(self, name: str, by: str) -> Removed:
        """Remove the user from the registry and its broker account (a broker account made outside
        the registry too); refused while it is mounted or checked in. Its certificates are revoked
        and it leaves the team and its site."""
        await self._check_name(name)
        recorded = await self._users.get_user(name)
        if recorded is None and await asyncio.to_thread(self._management.get_user, name) is None:
            raise NotFound(f"no user {name!r}")
        if problem := await in_use(self._channels, name):
            raise Conflict(problem)
        await self._check_revocable(name)
        await asyncio.to_thread(delete_account, self._admin_url, self._management, name)
        await self._users.remove_user(name)
        await self._sessions.end_all(name)
        await self._leave_sites(name)
        revoked = await self._revoke_certificates(name)
        log.info("user %s removed by %s", name, by)
        try:  # a warden removed no longer holds the hazard gate
            return Removed(await leave_team(self._team, self._admin_url, name, by), revoked)
        except HazardServiceNotTold as error:
            raise Unavailable(f"user {name} removed and taken out of the team, but {error}") from error

    async def _leave_sites(self, name: str) -> None:
        """Take a removed robot from its site: the site's account at central may no longer write
        for it, and the site is told to remove its copy of the account."""
        if self._sites is None:
            return
        for site, members in (await self._sites.sites()).items():
            if name in members:
                change = (await revise(self._sites, site, lambda listed: [r for r in listed if r != name]))[0]
                await grant_listed(self._sites, self._management, self._admin_url, site)
                if change.left:
                    await self.tell_site_to_remove(site, change.left, change.revision)

    async def tell_site_to_remove(
        self, site: str, robots: Collection[str], revision: int | None = None
    ) -> bool:
        """Send ``site`` the removal of its copies of ``robots``' accounts, as of its list's
        ``revision`` (None: as it is now); False (logged) when central's broker did not take it:
        the site keeps them, and the registry check reports them once the site says so (its
        repair sends the removal again)."""
        if revision is None and (listed := await self._site_registry().robots_of(site)) is not None:
            revision = listed.revision
        try:
            await asyncio.to_thread(send_removals, self._admin_url, site, robots, revision)
        except (AMQPError, OSError) as error:
            log.warning("site %s not told to remove %s: %s", site, ", ".join(robots), error)
            return False
        return True

    def _site_registry(self) -> SiteRegistry:
        if self._sites is None:
            raise Unavailable("this accounts service has no site registry")
        return self._sites

    async def _check_robots(self, robots: Collection[str]) -> None:
        """Refuse names that are no robots of the registry: a site forwards for robots only."""
        registry = {user.name: user for user in await self._users.users()}
        wrong = sorted(r for r in robots if r not in registry or registry[r].role is not UserRole.ROBOT)
        if wrong:
            raise BadRequest(
                f"not robots of the account registry: {', '.join(wrong)} "
                "(make them with `fleetbus users add NAME`)"
            )

    async def _assign_site(self, site: str, robots: Collection[str] | Decide) -> SiteRobots:
        try:
            names, sent, removed = await set_site_robots(
                self._site_registry(), self._team, self._management, self._admin_url, site, robots
            )
        except StaleRevision as error:  # changed by others again and again while this one tried
            raise Conflict(f"{error}; try again") from None
        except ValueError as error:
            raise BadRequest(str(error)) from None
        except (ManagementError, AMQPError, OSError) as error:
            problem = f"the broker refused or failed to give site {site} its robots: {error}"
            raise Unavailable(problem) from error
        return SiteRobots(names, sent, removed)

    async def add_site(
        self, site: str, robots: Collection[str], by: str, *, rotate: bool = False
    ) -> SiteAdded:
        """Make ``site``'s account at central (tagged impersonator, a new password), confined to
        ``robots`` (robots of the registry), and send the site their accounts. ``rotate``: an
        existing site gets a new password. A site's name is no user's."""
        try:
            validate_name(site)
        except ValueError as error:
            raise BadRequest(str(error)) from None
        if site == unquote(urlsplit(self._admin_url).username or ""):
            raise BadRequest(f"{site!r} is the broker administrator's account: no site may have that name")
        if await self._users.get_user(site) is not None:
            raise BadRequest(f"{site!r} is a user in the account registry: a site needs a name of its own")
        await self._check_robots(robots)
        try:
            account = await add_site_account(
                self._admin_url, self._management, site, rotate=rotate, cluster=self._cluster
            )
        except ValueError as error:
            raise Conflict(str(error)) from None
        except (ManagementError, AMQPError, OSError) as error:
            problem = f"the broker refused or failed to make site {site}'s account: {error}"
            raise Unavailable(problem) from error
        assigned = await self._assign_site(site, robots)
        log.info("site %s %s by %s", site, "re-keyed" if rotate else "made", by)
        public = as_public(account.amqp_url, self._public_url)
        return SiteAdded(assigned.robots, assigned.sent, assigned.removed, public, account.amqp_url)

    async def change_site_robots(
        self, site: str, add: Collection[str], remove: Collection[str], by: str
    ) -> SiteRobots:
        """Add robots of the registry to ``site`` and take others from it: its account at central
        follows, the site is sent the new ones' accounts and told to remove the others' copies."""
        known = await self._site_registry().sites()
        if site not in known:
            raise NotFound(f"no site {site!r}; make it with `fleetbus sites add {site}`")
        await self._check_robots(add)
        # from the site's list as it is when the change is made, not as read here
        changed = await self._assign_site(site, lambda listed: (set(listed) | set(add)) - set(remove))
        log.info("site %s: robots %s, by %s", site, ", ".join(changed.robots) or "none", by)
        return changed

    async def sync_site(self, site: str) -> SiteRobots:
        """Declare central's side of ``site``'s links again and grant its account its permissions
        (as this release has them), and send the site every one of its robots' accounts as central
        has them, then the list of its robots: the site removes its copies of the accounts central
        gave it that are not on it (robots removed at central or taken from the site, whose removal
        it missed), so a sync with nothing changed changes nothing there."""
        registry = self._site_registry()
        listed = await registry.robots_of(site)
        if listed is None:
            raise NotFound(f"no site {site!r}; make it with `fleetbus sites add {site}`")
        robots = listed.robots
        accounts = await robot_accounts(self._team, self._management, robots, listed.revision)
        roster = RobotRoster(names=list(robots), revision=listed.revision)
        try:  # what central takes from the site (made again if it went), then what it sends it
            await declare_with_url(self._admin_url, [central_site_topology(site, self._cluster)])
            await grant_listed(registry, self._management, self._admin_url, site)
            await asyncio.to_thread(send_to_sites, self._admin_url, [site], [*accounts, roster])
        except StaleRevision as error:
            raise Conflict(str(error)) from None
        except (AMQPError, OSError) as error:
            raise Unavailable(f"central's broker did not take site {site}'s accounts: {error}") from error
        log.info("site %s sent its robots' accounts and list: %s", site, ", ".join(robots) or "none")
        return SiteRobots(robots, accounts, [])

    async def login(
        self, name: str, password: str, origin: Origin, admit: Callable[[User], None] | None = None
    ) -> Login:
        """Check the password and begin a session seen from ``origin``; ``admit`` raises
        :class:`Forbidden` for a user this way in does not serve (before any session begins)."""
        user = await self._users.get_user(name)
        if (
            not await self._secrets.passwords.verify(user.password_hash if user else None, password)
            or user is None
        ):
            raise WrongCredentials("wrong user name or password")
        if user.role is UserRole.INACTIVE:
            raise Forbidden(f"user {name} is inactive: an admin must give it a role first")
        if admit is not None:
            admit(user)
        token = await self._sessions.begin(user.name, origin)
        return Login(user, token, self.broker_credentials(user))

    def broker_credentials(self, user: User) -> BrokerCredentials:
        """What the user is handed: its broker password and URL at the broker's public address."""
        internal = self.internal_broker_url(user)
        password = unquote(urlsplit(internal).password or "")
        return BrokerCredentials(
            user.name, password, vhost_of(self._admin_url), as_public(internal, self._public_url)
        )

    def broker_address(self, user: User) -> str:
        """The user's broker URL at the public address without its password: what may be on a page."""
        return as_public(url_for(self._admin_url, user.name, None), self._public_url)

    def internal_broker_url(self, user: User) -> str:
        """The user's login at the broker as this service reaches it (to publish as the user)."""
        if user.broker_secret is None:
            raise Unavailable(f"user {user.name} has no broker password on record")
        return url_for(self._admin_url, user.name, self._secrets.box.open(user.broker_secret))


def _seen_role(viewer: User, role: UserRole | None) -> UserRole | None:
    """The role of the accounts ``viewer`` may see when it asks for ``role`` (None: any)."""
    if viewer.role is UserRole.ADMIN:
        return role
    if viewer.role is UserRole.SUPERVISOR:
        if role not in (None, UserRole.ROBOT):
            raise Forbidden("a supervisor sees robots only")
        return UserRole.ROBOT
    raise Forbidden(f"role {viewer.role.value} sees no other accounts")


def known_use_cases(names: Iterable[str]) -> tuple[str, ...]:
    """``names`` in the order the service lists its use cases; :class:`BadRequest` naming an unknown one."""
    wanted = {name.strip() for name in names if name.strip()}
    if unknown := sorted(wanted - USE_CASES.keys()):
        raise BadRequest(f"no use case {', '.join(map(repr, unknown))}; use cases: {', '.join(USE_CASES)}")
    return tuple(name for name in USE_CASES if name in wanted)


def accounts_for(
    settings: Settings,
    repositories: Repositories,
    secrets_: Secrets,
    management: ManagementAPI,
    admin_url: str,
    public_url: str | None = None,
    sessions: Sessions | None = None,
) -> Accounts:
    """The accounts service as the HTTP API, the console and the command line all use it
    (``sessions``: the API's own; by default the store's sessions as the API keeps them)."""
    return Accounts(
        repositories.users,
        repositories.hazards,
        repositories.channels,
        secrets_,
        sessions or Sessions(repositories.sessions, secrets_.tokens, settings.api_sessions_per_user),
        management,
        admin_url,
        settings.ingest_shards,
        public_url or settings.public_amqp_url,
        cluster=settings.cluster,
        certificates=TlsFiles.for_settings(settings),
        sites=repositories.sites,
    )


@dataclass(frozen=True)
class AccountsContext:
    """The accounts service open for a block, with the repositories and the management API it uses."""

    accounts: Accounts
    repositories: Repositories
    management: ManagementAPI


@asynccontextmanager
async def open_accounts(
    settings: Settings, admin_url: str, management_url: str, public_url: str | None = None
) -> AsyncIterator[AccountsContext]:
    """The accounts service of a process that has no HTTP API of its own (the command line, the
    demo, the tests' helpers): the same service on the settings' store and ``admin_url``'s broker."""
    secrets_ = Secrets.for_settings(settings)
    try:
        async with open_repositories(settings) as repositories:
            with ManagementAPI.from_urls(management_url, admin_url) as management:
                accounts = accounts_for(settings, repositories, secrets_, management, admin_url, public_url)
                yield AccountsContext(accounts, repositories, management)
    finally:
        secrets_.passwords.close()


class WrongCredentials(Exception):
    """A login with an unknown user or a wrong password (told apart from neither in the answer)."""
