"""A mission's open hazards as the command line shows them, each with why a held one waits (the
hazard gate's rule, :func:`fleetbus.workers.team.why_held`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone

from fleetbus.workers.store.base import LARGEST_INTEGER, EventStore
from fleetbus.workers.store.hazards import DEFAULT_MISSION, CoordinationStore, Hazard, HazardState
from fleetbus.workers.team import gate, last_seen_of, why_held

__all__ = ["DEFAULT_MISSION", "LARGEST_INTEGER", "Hazard", "HazardState", "Hazards", "OpenHazard"]


@dataclass(frozen=True)
class OpenHazard:
    hazard: Hazard
    held_because: str
    """Why it is held; "" once announced."""


class Hazards:
    def __init__(self, hazards: CoordinationStore, events: EventStore) -> None:
        self._hazards = hazards
        self._events = events

    async def open(self, mission: str | None) -> list[OpenHazard]:
        """The mission's hazards not cleared yet (``None``: every mission's, by mission), in the
        order detected; the team and when its awaited wardens were last heard from are read only
        when one is held."""
        found = await self._hazards.open_hazards(mission)
        if not any(hazard.state is HazardState.HELD for hazard in found):
            return [OpenHazard(hazard, "") for hazard in found]
        state, now = gate(await self._hazards.robots()), datetime.now(timezone.utc)
        seen = await last_seen_of(self._events, state.waiting_for)
        return [OpenHazard(hazard, why_held(hazard, state, seen, now)) for hazard in found]

    async def recent(self, limit: int, offset: int = 0, state: HazardState | None = None) -> list[Hazard]:
        """Every hazard of every mission (or those in ``state``), cleared ones too, newest first."""
        return await self._hazards.recent_hazards(limit, offset, state)

    async def newest_by_state(
        self, states: Sequence[HazardState], limit: int
    ) -> dict[HazardState, list[Hazard]]:
        """The newest ``limit`` hazards of each of ``states``: bounded however many there are."""
        return {state: await self._hazards.recent_hazards(limit, state=state) for state in states}

    async def cleared(self, limit: int) -> list[Hazard]:
        """The ``limit`` hazards cleared last, of every mission, the last cleared first."""
        return await self._hazards.cleared_hazards(limit)

    async def during(self, since: datetime, until: datetime, limit: int) -> list[Hazard]:
        """The hazards that existed at some moment of [since, until) (received before its end, not
        cleared before its start), the ``limit`` received last, newest first: the live map's past."""
        return await self._hazards.hazards_during(since, until, limit)

    async def counts(self) -> dict[HazardState, int]:
        """How many hazards are in each state, of every mission (a state with none is left out)."""
        return await self._hazards.hazard_counts()
