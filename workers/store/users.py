"""The service layer's users: name, role, password hash and the broker password it hands over.

Passwords are stored only as argon2 hashes; the broker password is stored encrypted by the
service (``fleetbus.api.services.security.SecretBox``), because the login reply has to hand it back.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.base import StoreError
from fleetbus.workers.store.port import JSON, TEXT, TIME, Database, Doc, Index, Schema


@dataclass(frozen=True)
class User:
    name: str
    role: UserRole
    password_hash: str | None
    """argon2 hash; ``None`` for an account that cannot log in to the HTTP API yet."""
    broker_secret: str | None
    """The broker account's password, encrypted with the service's key."""
    kind: str | None
    """For robots: explorer, warden or guide."""
    created_at: datetime
    created_by: str
    updated_at: datetime
    use_cases: tuple[str, ...] | None = None
    """The use cases the user may create missions of; ``None``: every one, those added later too
    (as every account made before use cases were kept has it)."""


class UserExists(StoreError):
    pass


class NoSuchUser(StoreError):
    pass


class UserStore(abc.ABC):
    @abc.abstractmethod
    async def add_user(self, user: User) -> None:
        """Store a new user; raise :class:`UserExists` when the name is taken."""

    @abc.abstractmethod
    async def put_user(self, user: User) -> None:
        """Store ``user`` whole, over the one of its name if there is one."""

    @abc.abstractmethod
    async def get_user(self, name: str) -> User | None: ...

    @abc.abstractmethod
    async def users(self, role: UserRole | None = None) -> list[User]:
        """Users by name, optionally only those of one role."""

    @abc.abstractmethod
    async def update_user(
        self,
        name: str,
        at: datetime,
        *,
        role: UserRole | None = None,
        password_hash: str | None = None,
        broker_secret: str | None = None,
    ) -> User:
        """Change the given fields (``None`` leaves one as it is); raise :class:`NoSuchUser`."""

    @abc.abstractmethod
    async def set_use_cases(self, name: str, use_cases: tuple[str, ...] | None, at: datetime) -> User:
        """Keep the use cases ``name`` may create missions of (``None``: every one); raise
        :class:`NoSuchUser`."""

    @abc.abstractmethod
    async def remove_user(self, name: str) -> bool:
        """Delete the user; False when there was none."""


USERS = Schema(
    "users",
    {
        "name": TEXT,
        "role": TEXT,
        "password_hash": TEXT.maybe,
        "broker_secret": TEXT.maybe,
        "kind": TEXT.maybe,
        "created_at": TIME,
        "created_by": TEXT,
        "updated_at": TIME,
        "use_cases": JSON.maybe,
    },
    key=("name",),
    indexes=(Index("role", "name"),),
)


def _user(doc: Doc) -> User:
    use_cases = doc["use_cases"]
    return User(
        **{**doc, "role": UserRole(doc["role"]), "use_cases": None if use_cases is None else tuple(use_cases)}
    )


def _doc(user: User) -> Doc:
    use_cases = None if user.use_cases is None else list(user.use_cases)
    return {**user.__dict__, "role": user.role.value, "use_cases": use_cases}


class Users(UserStore):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._users = database.collection(USERS)

    async def add_user(self, user: User) -> None:
        if not (await self._users.insert([_doc(user)]))[0]:
            raise UserExists(f"user {user.name!r} exists")

    async def put_user(self, user: User) -> None:
        await self._users.put(_doc(user))

    async def get_user(self, name: str) -> User | None:
        doc = await self._users.get(name)
        return _user(doc) if doc else None

    async def users(self, role: UserRole | None = None) -> list[User]:
        where = {} if role is None else {"role": role.value}
        return [_user(doc) for doc in await self._users.find(where, order=["name"])]

    async def update_user(
        self,
        name: str,
        at: datetime,
        *,
        role: UserRole | None = None,
        password_hash: str | None = None,
        broker_secret: str | None = None,
    ) -> User:
        changes = {
            "role": role.value if role else None,
            "password_hash": password_hash,
            "broker_secret": broker_secret,
        }
        given = {field: value for field, value in changes.items() if value is not None}
        return await self._change(name, {**given, "updated_at": at})

    async def set_use_cases(self, name: str, use_cases: tuple[str, ...] | None, at: datetime) -> User:
        kept = None if use_cases is None else list(use_cases)
        return await self._change(name, {"use_cases": kept, "updated_at": at})

    async def _change(self, name: str, changes: Doc) -> User:
        async def update() -> User:
            await self._users.update({"name": name}, changes)
            user = await self.get_user(name)
            if user is None:
                raise NoSuchUser(f"no user {name!r}")
            return user

        return await self._database.transaction(update)

    async def remove_user(self, name: str) -> bool:
        return await self._users.delete({"name": name}) == 1
