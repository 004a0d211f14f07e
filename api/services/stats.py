"""How the workers fare, as ``fleetbus stats`` shows it: each worker's latest status, and what
each bound on growth removed since the store began (records pruned, messages full queues dropped)."""

from __future__ import annotations

from fleetbus.api.services.errors import Unavailable
from fleetbus.workers.store.base import StoreError
from fleetbus.workers.store.housekeeping import BoundCount, Housekeeping
from fleetbus.workers.store.statuses import StatusBoard, WorkerStatus

__all__ = ["BoundCount", "Stats", "WorkerStatus"]


class Stats:
    def __init__(self, statuses: StatusBoard, housekeeping: Housekeeping) -> None:
        self._statuses = statuses
        self._housekeeping = housekeeping

    async def workers(self) -> list[WorkerStatus]:
        """Each worker's latest status (a worker writes it every few seconds); refused as
        unavailable when the store does not answer, for a caller that shows the rest without it."""
        try:
            return await self._statuses.statuses()
        except StoreError as error:
            raise Unavailable(f"the store did not answer ({error})") from None

    async def removed(self) -> list[BoundCount]:
        """What each bound removed, by bound then subject."""
        return await self._housekeeping.bound_counts()
