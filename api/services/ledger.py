"""The sequence ledger as ``fleetbus query gaps`` and ``fleetbus query duplicates`` (and the
console's dashboard, for the gaps) show it: the open gaps in the robots' sequence numbers, and the
duplicates the workers recognised."""

from __future__ import annotations

from fleetbus.workers.store.ledger import Duplicate, Gap, SequenceLedger

__all__ = ["Duplicate", "Gap", "Ledger"]


class Ledger:
    def __init__(self, ledger: SequenceLedger) -> None:
        self._ledger = ledger

    async def gaps(self, robot_id: str | None = None) -> list[Gap]:
        """Open gaps (of ``robot_id``, else every robot's), by robot, epoch, then first missing number."""
        return await self._ledger.gaps(robot_id)

    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        """Duplicates seen (of ``robot_id``, else every robot's), newest first."""
        return await self._ledger.duplicates(robot_id, limit)
