"""The beacon registry and where people are likely stranded (:mod:`fleetbus.workers.beacons`), as
the command line loads and shows them and the console maps them; and what the beacon exchange
discarded (:class:`BeaconDiscards`)."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from typing import Any

from pydantic import BaseModel, ConfigDict, FiniteFloat, ValidationError
from pydantic_core import ErrorDetails

from fleetbus.api.services.errors import BadRequest
from fleetbus.workers.beacons import stranded, window_refusal
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.beacons import Beacon, BeaconRegistry
from fleetbus.workers.store.discards import Discard, DiscardCount, DiscardLog


class BeaconEntry(BaseModel):
    """One beacon of a list to load: where it is, in the map frame's metres (finite: a beacon at
    NaN or infinity is nowhere a guide can go)."""

    model_config = ConfigDict(coerce_numbers_to_str=True)

    id: str
    x: FiniteFloat
    y: FiniteFloat
    label: str | None = None


def _problem(error: ErrorDetails) -> str:
    field = ".".join(str(part) for part in error["loc"])
    if error["type"] == "missing":
        return f"{field} is missing (a beacon needs id, x and y)"
    return f"{field} must be {error['msg'].removeprefix('Input should be ')}, not {error['input']!r}"


def beacons_of(entries: object) -> list[Beacon]:
    """The beacons of a list of ``{id, x, y, label}`` (a label is optional); :class:`BadRequest`
    naming the first entry that is not one, and its field."""
    if not isinstance(entries, list):
        raise BadRequest("expected a list of beacons with id, x, y and label")
    beacons = []
    for number, entry in enumerate(entries, 1):
        if not isinstance(entry, dict):
            raise BadRequest(f"beacon {number}: expected {{id, x, y, label}}, not {entry!r}")
        try:
            valid = BeaconEntry.model_validate(entry)
        except ValidationError as error:
            problems = "; ".join(_problem(e) for e in error.errors(include_url=False))
            raise BadRequest(f"beacon {number}: {problems}") from None
        beacons.append(Beacon(valid.id, valid.x, valid.y, valid.label or ""))
    return beacons


class Beacons:
    def __init__(self, registry: BeaconRegistry, events: EventStore, max_window: timedelta) -> None:
        self._registry = registry
        self._events = events
        self._max_window = max_window

    async def load(self, entries: object) -> list[Beacon]:
        """Add or update the beacons of ``entries`` (:func:`beacons_of`): all of them, or none
        when one is not a beacon."""
        beacons = beacons_of(entries)
        await self._registry.put_beacons(beacons)
        return beacons

    async def registry(self) -> list[Beacon]:
        return await self._registry.beacons()

    async def stranded(self, since: datetime) -> list[dict[str, Any]]:
        """Beacons heard since ``since``: where people are likely stranded, first heard first;
        :class:`BadRequest` for a ``since`` further back than the bound."""
        if refusal := window_refusal(datetime.now(timezone.utc) - since, self._max_window):
            raise BadRequest(refusal)
        return await stranded(self._registry, self._events, since)


class BeaconDiscards:
    """The beacon messages the broker discarded (without the ``type: beacon`` and ``codename``
    headers), as the workers logged them."""

    def __init__(self, discards: DiscardLog) -> None:
        self._discards = discards

    async def counts(self) -> list[DiscardCount]:
        """Per publishing exchange: how many, and the latest one's time and reason; by exchange."""
        return await self._discards.discard_counts()

    async def recent(self, limit: int) -> list[Discard]:
        """The latest ``limit`` discards, newest first."""
        return await self._discards.recent_discards(limit)
