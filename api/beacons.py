"""The beacon registry and where people are likely stranded (:mod:`fleetbus.workers.beacons`), as
the command line loads and shows them and the console maps them; and what the beacon exchange
discarded (:class:`BeaconDiscards`)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from fleetbus.api.errors import BadRequest
from fleetbus.workers.beacons import stranded
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.beacons import Beacon, BeaconRegistry
from fleetbus.workers.store.discards import Discard, DiscardCount, DiscardLog


def beacons_of(entries: object) -> list[Beacon]:
    """The beacons of a list of ``{id, x, y, label}`` (a label is optional); :class:`BadRequest`
    naming the first entry that is not one."""
    if not isinstance(entries, list):
        raise BadRequest("expected a list of beacons with id, x, y and label")
    beacons = []
    for number, entry in enumerate(entries, 1):
        try:
            beacons.append(
                Beacon(str(entry["id"]), float(entry["x"]), float(entry["y"]), str(entry.get("label", "")))
            )
        except (KeyError, TypeError, ValueError) as error:
            raise BadRequest(f"beacon {number}: needs id, x and y ({error!r})") from None
    return beacons


class Beacons:
    def __init__(self, registry: BeaconRegistry, events: EventStore) -> None:
        self._registry = registry
        self._events = events

    async def load(self, entries: object) -> list[Beacon]:
        """Add or update the beacons of ``entries`` (:func:`beacons_of`): all of them, or none
        when one is not a beacon."""
        beacons = beacons_of(entries)
        await self._registry.put_beacons(beacons)
        return beacons

    async def registry(self) -> list[Beacon]:
        return await self._registry.beacons()

    async def stranded(self, since: datetime) -> list[dict[str, Any]]:
        """Beacons heard since ``since``: where people are likely stranded, first heard first."""
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
