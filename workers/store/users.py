"""The service layer's users: name, role, password hash and the broker password it hands over.

Passwords are stored only as argon2 hashes; the broker password is stored encrypted by the
service (``fleetbus.api.security.SecretBox``), because the login reply has to hand it back.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.base import StoreError


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


class UserExists(StoreError):
    pass


class NoSuchUser(StoreError):
    pass


class UserStore(abc.ABC):
    @abc.abstractmethod
    async def add_user(self, user: User) -> None:
        """Store a new user; raise :class:`UserExists` when the name is taken."""

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
    async def remove_user(self, name: str) -> bool:
        """Delete the user; False when there was none."""
