"""Users of the service layer: create, change role, remove, log in; each with its broker account.

The store holds the user (role, password hash, encrypted broker password); the broker holds an
account of the same name with a random password, confined to ``^<name>\\.``. The store is
written first, so a name is claimed atomically; a broker failure then undoes the store write.
An ``inactive`` user's broker account has no permissions at all: it cannot even connect.
Client certificates fleetbus's CA signed for a name are revoked when a user of that name is made or
removed, as ``fleetbus users add`` and ``remove`` do: a later account of that name must not
inherit them. A password set, a user disabled and a user removed end the user's login sessions
(but the one that changed its own password).
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from dataclasses import dataclass
from datetime import datetime, timezone
from urllib.parse import unquote, urlsplit

from fleetbus.api.errors import BadRequest, Conflict, Forbidden, NotFound, Unavailable
from fleetbus.api.security import Secrets, Token, password_problem
from fleetbus.api.sessions import Origin, Sessions, end_sessions_of
from fleetbus.broker.account_roles import ROLE_TAGS, Role
from fleetbus.broker.accounts import (
    as_public,
    configure_account,
    delete_account,
    revoke_account,
    url_for,
    vhost_of,
)
from fleetbus.broker.certificates import CertificateError, TlsFiles
from fleetbus.broker.management import ManagementAPI, ManagementError
from fleetbus.broker.revocation import cannot_revoke, revoke_certificates_of, revoked_summary
from fleetbus.broker.team_changes import HazardServiceNotTold
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.channels import ChannelStore
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
    ) -> None:
        """``public_url``: the broker as users and robots reach it (no credentials), for the URLs
        handed out; None: ``admin_url``'s broker. ``certificates``: fleetbus's CA, whose
        certificates for a name are revoked when a user of that name is made or removed."""
        self._certificates = certificates
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

    async def _broker(self, name: str, role: UserRole, kind: str | None, password: str | None = None) -> None:
        """Bring the broker account in line with the role (and set its password when given)."""

        def apply() -> None:
            if password is not None:
                self._management.put_user(name, password, ROLE_TAGS[broker_role(role)])
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

    async def _check_revocable(self, name: str) -> None:
        """Refuse before anything changes when ``name``'s certificates could not be revoked."""
        if self._certificates is not None:
            if problem := await asyncio.to_thread(cannot_revoke, self._certificates, name):
                raise Unavailable(problem)

    async def _revoke_certificates(self, name: str) -> None:
        if self._certificates is None:
            return
        try:
            revoked = await asyncio.to_thread(revoke_certificates_of, self._certificates, name)
        except CertificateError as error:
            raise Unavailable(f"could not revoke the certificates of {name}: {error}") from error
        if revoked:
            log.warning("%s", revoked_summary(name, revoked))

    async def create(
        self, name: str, password: str | None, role: UserRole, kind: RobotKind | None, by: str
    ) -> User:
        """A new user and its broker account; ``password`` ``None``: cannot log in until one is set."""
        try:
            validate_name(name)
        except ValueError as error:
            raise BadRequest(str(error)) from None
        if kind is not None and role is not UserRole.ROBOT:
            raise BadRequest("kind applies to robots only")
        if password is not None and (problem := password_problem(password)):
            raise BadRequest(problem)
        if await asyncio.to_thread(self._management.get_user, name) is not None:
            if await self._users.get_user(name) is None:
                raise Conflict(f"a broker account named {name!r} exists outside the service; remove it first")
        await self._check_revocable(name)
        now = datetime.now(timezone.utc)
        broker_password = secrets.token_urlsafe(24)
        user = User(
            name=name,
            role=role,
            password_hash=await self._secrets.passwords.hash(password) if password is not None else None,
            broker_secret=self._secrets.box.seal(broker_password),
            kind=kind.value if kind else None,
            created_at=now,
            created_by=by,
            updated_at=now,
        )
        try:
            await self._users.add_user(user)
        except UserExists:
            raise Conflict(f"user {name!r} exists") from None
        try:
            await self._broker(name, role, user.kind, password=broker_password)
        except Unavailable:
            await self._users.remove_user(name)
            await asyncio.to_thread(self._management.delete_user, name)
            raise
        if role is UserRole.ROBOT:
            await self._team.register_robot(name, user.kind)
        await self._revoke_certificates(name)
        log.info("user %s created by %s with role %s", name, by, role.value)
        return user

    async def get(self, name: str) -> User:
        user = await self._users.get_user(name)
        if user is None:
            raise NotFound(f"no user {name!r}")
        return user

    async def set_role(self, name: str, role: UserRole, by: str) -> User:
        """Give ``name`` another role (``inactive`` disables it); ``by`` is the admin who does it."""
        if name == by and role is not UserRole.ADMIN:
            raise BadRequest("an admin cannot take its own admin role away (ask another admin)")
        user = await self.get(name)
        if user.kind is not None and role is not UserRole.ROBOT and role is not UserRole.INACTIVE:
            raise BadRequest(f"{name} is a robot ({user.kind}); it can be a robot or inactive")
        await self._broker(name, role, user.kind)
        changed = await self._users.update_user(name, datetime.now(timezone.utc), role=role)
        if role is UserRole.INACTIVE:  # else they would open again when it is given a role
            await self._sessions.end_all(name)
        log.info("user %s: role %s -> %s, by %s", name, user.role.value, role.value, by)
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

    async def remove(self, name: str, by: str) -> None:
        await self.get(name)
        mounts = await self._channels.mounts(operator=name) + await self._channels.mounts(robot=name)
        if mounts or await self._channels.check_ins(operator=name):
            held = ", ".join(f"{m.robot} mounted by {m.operator} for {m.mission_id}" for m in mounts)
            raise Conflict(f"{name} is in use ({held or 'checked in'}); unmount and check out first")
        await self._check_revocable(name)
        await asyncio.to_thread(delete_account, self._admin_url, self._management, name)
        await self._users.remove_user(name)
        await self._sessions.end_all(name)
        await self._revoke_certificates(name)
        log.info("user %s removed by %s", name, by)
        try:  # a warden removed no longer holds the hazard gate
            await leave_team(self._team, self._admin_url, name, by)
        except HazardServiceNotTold as error:
            raise Unavailable(f"user {name} removed and taken out of the team, but {error}") from error

    async def login(self, name: str, password: str, origin: Origin) -> Login:
        """Check the password and begin a session seen from ``origin``."""
        user = await self._users.get_user(name)
        if (
            not await self._secrets.passwords.verify(user.password_hash if user else None, password)
            or user is None
        ):
            raise WrongCredentials("wrong user name or password")
        if user.role is UserRole.INACTIVE:
            raise Forbidden(f"user {name} is inactive: an admin must give it a role first")
        token = await self._sessions.begin(user.name, origin)
        return Login(user, token, self.broker_credentials(user))

    def broker_credentials(self, user: User) -> BrokerCredentials:
        """What the user is handed: its broker password and URL at the broker's public address."""
        internal = self.internal_broker_url(user)
        password = unquote(urlsplit(internal).password or "")
        return BrokerCredentials(
            user.name, password, vhost_of(self._admin_url), as_public(internal, self._public_url)
        )

    def internal_broker_url(self, user: User) -> str:
        """The user's login at the broker as this service reaches it (to publish as the user)."""
        if user.broker_secret is None:
            raise Unavailable(f"user {user.name} has no broker password on record")
        return url_for(self._admin_url, user.name, self._secrets.box.open(user.broker_secret))


class WrongCredentials(Exception):
    """A login with an unknown user or a wrong password (told apart from neither in the answer)."""
