"""What ``fleetbus shards`` reads of the store: the workers' leases (which worker holds which
shard) and the account registry's robots, the only names a shard is for."""

from __future__ import annotations

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.leases import Lease, LeaseStore
from fleetbus.workers.store.users import UserStore

__all__ = ["Lease", "Shards"]


class Shards:
    def __init__(self, leases: LeaseStore, users: UserStore) -> None:
        self._leases = leases
        self._users = users

    async def leases(self) -> list[Lease]:
        return await self._leases.leases()

    async def robots(self) -> list[str]:
        return [user.name for user in await self._users.users(UserRole.ROBOT)]
